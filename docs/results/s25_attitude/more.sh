cd /work/wt/attitude
export CANOPY_CACHE_DIR=/work/cache PYTHONPATH=/work/wt/attitude
R="--set tracking.vertical_estimate=true --set mapping.attitude_prior=true"
T2="$R --set tracking.vertical_track_prior=true --set tracking.vertical_sigma_scale=2"
g() { out=$1 ds=$2 gn=$3 bt=$4 fr=$5 sd=$6; shift 6
  python benchmarks/bench_degrade_grid.py --in-process --cells-cache /tmp/attitude-cache --methods auto --skip-clean --peers \
    --seed $sd --datasets $ds --gains $gn --betas $bt --noise high --max-frames $fr --out-dir /tmp/attitude/grid/$out "$@" 2>&1 | grep "ATE" | grep -v "^dataset" | sed "s/^/$out /"; }
c() { out=$1 ds=$2 fr=$3; shift 3; echo "$out $(python benchmarks/diagnose_pitch.py --no-counterfactuals --path /work/cache/synthetic/$ds-seed0-full --clean /work/cache/synthetic/$ds-seed0-full --max-frames $fr "$@" 2>&1 | grep '^ATE')"; }
g trk2-dl1b006-s0 day-loop 1 0.06 300 0 $T2
g trk2-hr1b006-s0 haze-row 1 0.06 346 0 $T2
for cfg in base ba1 trk2; do
  case $cfg in base) X="";; ba1) X="$R";; trk2) X="$T2";; esac
  g $cfg-dl1b0-s0 day-loop 1 0 300 0 $X
  g $cfg-hr1b0-s0 haze-row 1 0 346 0 $X
done
g trk2-dr1b0-s0 dark-rows 1 0 150 0 $T2
c trk2-clean-dl day-loop 300 $T2
for cfg in base ba1 trk2; do
  case $cfg in base) X="";; ba1) X="$R";; trk2) X="$T2";; esac
  c $cfg-clean-hr haze-row 346 $X
  c $cfg-clean-dr dark-rows 150 $X
done
for s in 1 2; do
  g trk2-dl1b006-s$s day-loop 1 0.06 300 $s $T2
  g trk2-hr1b006-s$s haze-row 1 0.06 346 $s $T2
  g base-hr1b006-s$s haze-row 1 0.06 346 $s
done
