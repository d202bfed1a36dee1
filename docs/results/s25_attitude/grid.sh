cd /work/wt/attitude
export CANOPY_CACHE_DIR=/work/cache PYTHONPATH=/work/wt/attitude
R="--set tracking.vertical_estimate=true --set mapping.attitude_prior=true"
g() { # out ds gain beta frames seed extra
  out=$1 ds=$2 gn=$3 bt=$4 fr=$5 sd=$6; shift 6
  python benchmarks/bench_degrade_grid.py --in-process --cells-cache /tmp/attitude-cache --methods auto --skip-clean --peers \
    --seed $sd --datasets $ds --gains $gn --betas $bt --noise high --max-frames $fr --out-dir /tmp/attitude/grid/$out "$@" 2>&1 | grep "ATE"
}
for s in 0 1 2; do
  echo "dl g0.15-b0 s$s"; g base-dl015b0-s$s day-loop 0.15 0 300 $s; g real-dl015b0-s$s day-loop 0.15 0 300 $s $R
done
for s in 0 1 2; do
  echo "dl g1-b0.06 s$s"; g base-dl1b006-s$s day-loop 1 0.06 300 $s; g real-dl1b006-s$s day-loop 1 0.06 300 $s $R
done
for s in 0 1 2; do
  echo "dr g1-b0.06 s$s"; g real-dr1b006-s$s dark-rows 1 0.06 150 $s $R
done
echo "dr g1-b0 s0"; g base-dr1b0-s0 dark-rows 1 0 150 0; g real-dr1b0-s0 dark-rows 1 0 150 0 $R
echo "hr g1-b0.06 s0"; g base-hr1b006-s0 haze-row 1 0.06 346 0; g real-hr1b006-s0 haze-row 1 0.06 346 0 $R
echo "dl g0.15-b0.06 s0 via grid"; g real-dl015b006-s0 day-loop 0.15 0.06 300 0 $R
