cd /work/wt/attitude
export CANOPY_CACHE_DIR=/work/cache PYTHONPATH=/work/wt/attitude
X="--set tracking.vertical_estimate=true --set mapping.attitude_prior=true --set tracking.vertical_max_sigma_deg=0.3"
g() { out=$1 ds=$2 gn=$3 bt=$4 fr=$5 sd=$6; shift 6
  python benchmarks/bench_degrade_grid.py --in-process --cells-cache /tmp/attitude-cache --methods auto --skip-clean --peers \
    --seed $sd --datasets $ds --gains $gn --betas $bt --noise high --max-frames $fr --out-dir /tmp/attitude/grid/$out "$@" 2>&1 | grep "ATE" | grep -v "^dataset" | sed "s/^/$out /"; }
c() { out=$1 ds=$2 fr=$3; shift 3; echo "$out $(python benchmarks/diagnose_pitch.py --no-counterfactuals --path /work/cache/synthetic/$ds-seed0-full --clean /work/cache/synthetic/$ds-seed0-full --max-frames $fr "$@" 2>&1 | grep '^ATE\|measured up')"; }
g sig03-dl1b006-s0 day-loop 1 0.06 300 0 $X
g sig03-hr1b006-s0 haze-row 1 0.06 346 0 $X
g sig03-hr1b0-s0 haze-row 1 0 346 0 $X
g sig03-dl1b0-s0 day-loop 1 0 300 0 $X
g sig03-dr1b006-s0 dark-rows 1 0.06 150 0 $X
g sig03-dr1b006-s2 dark-rows 1 0.06 150 2 $X
c sig03-clean-dl day-loop 300 $X
c sig03-clean-hr haze-row 346 $X
c sig03-clean-dr dark-rows 150 $X
