cd /work/wt/attitude
export CANOPY_CACHE_DIR=/work/cache PYTHONPATH=/work/wt/attitude
while pgrep -f more.sh > /dev/null; do sleep 5; done
R="--set tracking.vertical_estimate=true --set mapping.attitude_prior=true"
g() { out=$1 ds=$2 gn=$3 bt=$4 fr=$5 sd=$6; shift 6
  python benchmarks/bench_degrade_grid.py --in-process --cells-cache /tmp/attitude-cache --methods auto --skip-clean --peers \
    --seed $sd --datasets $ds --gains $gn --betas $bt --noise high --max-frames $fr --out-dir /tmp/attitude/grid/$out "$@" 2>&1 | grep "ATE" | grep -v "^dataset" | sed "s/^/$out /"; }
for cfg in ref5 sig03; do
  case $cfg in ref5) X="$R --set mapping.attitude_reference_keyframes=5";; sig03) X="$R --set tracking.vertical_max_sigma_deg=0.3";; esac
  for s in 0 1 2; do g $cfg-dl015b0-s$s day-loop 0.15 0 300 $s $X; done
  g $cfg-dr1b0-s0 dark-rows 1 0 150 0 $X
  g $cfg-dr1b006-s1 dark-rows 1 0.06 150 1 $X
  for s in 0 1 2; do g $cfg-dl015b006-s$s day-loop 0.15 0.06 300 $s $X; done
done
