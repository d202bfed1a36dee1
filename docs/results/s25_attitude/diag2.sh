cd /work/wt/attitude
export CANOPY_CACHE_DIR=/work/cache PYTHONPATH=/work/wt/attitude

R="--set tracking.vertical_estimate=true --set mapping.attitude_prior=true"
C=/tmp/attitude-cache
run() { tag=$1; shift; echo "=== $tag"; python benchmarks/diagnose_pitch.py --no-counterfactuals --path "$@" 2>&1 | grep -v "Warn\|increments per\|first keyframe"; }
run "base dl015b0 s0" $C/day-loop-300-g0.15-b0-high-seed0 --clean /work/cache/synthetic/day-loop-seed0-full --max-frames 300
run "ba1 dl015b0 s0" $C/day-loop-300-g0.15-b0-high-seed0 --clean /work/cache/synthetic/day-loop-seed0-full --max-frames 300 $R
run "oracle0.2 dl015b0 s0" $C/day-loop-300-g0.15-b0-high-seed0 --clean /work/cache/synthetic/day-loop-seed0-full --max-frames 300 --oracle-up 0.2
