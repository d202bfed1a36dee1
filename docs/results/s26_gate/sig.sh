cd /work/wt/gate
export CANOPY_CACHE_DIR=/work/cache PYTHONPATH=/work/wt/gate CANOPY_VERTICAL_GATE_DEBUG=1
X="--set tracking.vertical_estimate=true --set tracking.vertical_max_sigma_deg=0.3"
g() { out=$1 ds=$2 gn=$3 bt=$4 fr=$5 sd=$6; shift 6
  /usr/bin/time -f "%e s" python benchmarks/bench_degrade_grid.py --in-process --cells-cache /tmp/attitude-cache --methods auto --skip-clean \
    --seed $sd --datasets $ds --gains $gn --betas $bt --noise high --max-frames $fr --out-dir /tmp/gate/grid/$out "$@" > /tmp/gate/$out.log 2>&1
  echo "$out $(grep -c VGATE /tmp/gate/$out.log) $(tail -1 /tmp/gate/$out.log)"; }
g sig2-dl015b006-s0 day-loop 0.15 0.06 300 0 $X
g sig2-dl015b0-s0 day-loop 0.15 0 300 0 $X
g sig2-dl1b006-s0 day-loop 1 0.06 300 0 $X
g sig2-dl1b0-s0 day-loop 1 0 300 0 $X
g sig2-dr1b0-s0 dark-rows 1 0 150 0 $X
g sig2-dr1b006-s0 dark-rows 1 0.06 150 0 $X
g sig2-hr1b006-s0 haze-row 1 0.06 346 0 $X
