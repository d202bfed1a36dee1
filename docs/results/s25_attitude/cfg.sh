cd /work/wt/attitude
export CANOPY_CACHE_DIR=/work/cache PYTHONPATH=/work/wt/attitude
R="--set tracking.vertical_estimate=true --set mapping.attitude_prior=true"
g() { out=$1 ds=$2 gn=$3 bt=$4 fr=$5 sd=$6; shift 6
  python benchmarks/bench_degrade_grid.py --in-process --cells-cache /tmp/attitude-cache --methods auto --skip-clean --peers \
    --seed $sd --datasets $ds --gains $gn --betas $bt --noise high --max-frames $fr --out-dir /tmp/attitude/grid/$out "$@" 2>&1 | grep "ATE" | sed "s/^/$out /"; }
for cfg in trk1 ba2 trk2; do
  case $cfg in
    trk1) X="$R --set tracking.vertical_track_prior=true";;
    ba2) X="$R --set tracking.vertical_sigma_scale=2";;
    trk2) X="$R --set tracking.vertical_track_prior=true --set tracking.vertical_sigma_scale=2";;
  esac
  for s in 0 1 2; do
    g $cfg-dl015b006-s$s day-loop 0.15 0.06 300 $s $X
    g $cfg-dl015b0-s$s day-loop 0.15 0 300 $s $X
    g $cfg-dr1b006-s$s dark-rows 1 0.06 150 $s $X
  done
done
