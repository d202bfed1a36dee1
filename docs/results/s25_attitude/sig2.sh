cd /work/wt/attitude
export CANOPY_CACHE_DIR=/work/cache PYTHONPATH=/work/wt/attitude
X="--set tracking.vertical_estimate=true --set mapping.attitude_prior=true --set tracking.vertical_max_sigma_deg=0.3"
g() { out=$1 ds=$2 gn=$3 bt=$4 fr=$5 sd=$6; shift 6
  python benchmarks/bench_degrade_grid.py --in-process --cells-cache /tmp/attitude-cache --methods auto --skip-clean --peers \
    --seed $sd --datasets $ds --gains $gn --betas $bt --noise high --max-frames $fr --out-dir /tmp/attitude/grid/$out "$@" 2>&1 | grep "ATE" | grep -v "^dataset" | sed "s/^/$out /"; }
for s in 1 2; do
  g base-dr1b0-s$s dark-rows 1 0 150 $s; g sig03-dr1b0-s$s dark-rows 1 0 150 $s $X
  g sig03-dl1b006-s$s day-loop 1 0.06 300 $s $X
  g base-dl1b0-s$s day-loop 1 0 300 $s; g sig03-dl1b0-s$s day-loop 1 0 300 $s $X
done
g base-dl006b006-s0 day-loop 0.06 0.06 300 0; g sig03-dl006b006-s0 day-loop 0.06 0.06 300 0 $X
g base-dl006b0-s0 day-loop 0.06 0 300 0; g sig03-dl006b0-s0 day-loop 0.06 0 300 0 $X
g base-hr015b0-s0 haze-row 0.15 0 346 0; g sig03-hr015b0-s0 haze-row 0.15 0 346 0 $X
g base-dr015b006-s0 dark-rows 0.15 0.06 150 0; g sig03-dr015b006-s0 dark-rows 0.15 0.06 150 0 $X
g base-hr015b006-s0 haze-row 0.15 0.06 346 0; g sig03-hr015b006-s0 haze-row 0.15 0.06 346 0 $X
