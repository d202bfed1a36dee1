# usage: run.sh TAG "extra --set args" seeds...
cd /work/wt/gate
export CANOPY_CACHE_DIR=/work/cache PYTHONPATH=/work/wt/gate CANOPY_VERTICAL_GATE_DEBUG=1
TAG=$1; EXTRA=$2; shift 2
X="--set tracking.vertical_estimate=true --set mapping.attitude_prior=true --set tracking.vertical_max_sigma_deg=0.3 $EXTRA"
g() { out=$1 ds=$2 gn=$3 bt=$4 fr=$5 sd=$6; shift 6
  python benchmarks/bench_degrade_grid.py --in-process --cells-cache /tmp/attitude-cache --methods auto --skip-clean \
    --seed $sd --datasets $ds --gains $gn --betas $bt --noise high --max-frames $fr --out-dir /tmp/gate/grid/$out "$@" > /tmp/gate/$out.log 2>&1
  echo "$out open $(grep -c 'VGATE.*open 1' /tmp/gate/$out.log)/$(grep -c VGATE /tmp/gate/$out.log) $(grep '| day-loop\|| dark-rows\|| haze-row' /tmp/gate/$out.log | head -1 | cut -d'|' -f3,5)"; }
c() { out=$1 ds=$2 fr=$3; shift 3; python benchmarks/diagnose_pitch.py --no-counterfactuals --path /work/cache/synthetic/$ds-seed0-full --clean /work/cache/synthetic/$ds-seed0-full --max-frames $fr "$@" > /tmp/gate/$out.log 2>&1
  echo "$out open $(grep -c 'VGATE.*open 1' /tmp/gate/$out.log)/$(grep -c VGATE /tmp/gate/$out.log) $(grep '^ATE' /tmp/gate/$out.log)"; }
for s in "$@"; do
  if [ "$s" = clean ]; then
    c $TAG-clean-dl day-loop 300 $X; c $TAG-clean-hr haze-row 346 $X; c $TAG-clean-dr dark-rows 150 $X; continue; fi
  g $TAG-dl015b006-s$s day-loop 0.15 0.06 300 $s $X
  g $TAG-dl015b0-s$s day-loop 0.15 0 300 $s $X
  g $TAG-dl1b006-s$s day-loop 1 0.06 300 $s $X
  g $TAG-dl1b0-s$s day-loop 1 0 300 $s $X
  g $TAG-dr1b0-s$s dark-rows 1 0 150 $s $X
  g $TAG-dr1b006-s$s dark-rows 1 0.06 150 $s $X
  g $TAG-hr1b006-s$s haze-row 1 0.06 346 $s $X
done
