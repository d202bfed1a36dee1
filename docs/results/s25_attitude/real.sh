cd /work/wt/attitude
export CANOPY_CACHE_DIR=/work/cache PYTHONPATH=/work/wt/attitude
C=/tmp/attitude-cache
R="--set tracking.vertical_estimate=true --set mapping.attitude_prior=true"
run() { tag=$1; shift; echo "=== $tag"; python benchmarks/diagnose_pitch.py --no-counterfactuals --path "$@" 2>&1 | grep -v "Warn\|increments per\|first keyframe"; }
for s in 0 1 2; do
  run "real dl-haze s$s" $C/day-loop-300-g0.15-b0.06-high-seed$s-rendered --clean /work/cache/synthetic/day-loop-seed0-full --max-frames 300 $R
done
run "real dl-clean" /work/cache/synthetic/day-loop-seed0-full --clean /work/cache/synthetic/day-loop-seed0-full --max-frames 300 $R
