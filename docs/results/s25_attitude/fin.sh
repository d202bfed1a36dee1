cd /work/wt/attitude
export CANOPY_CACHE_DIR=/work/cache PYTHONPATH=/work/wt/attitude
while pgrep -f var.sh > /dev/null; do sleep 5; done
R="--set tracking.vertical_estimate=true --set mapping.attitude_prior=true"
g() { out=$1 ds=$2 gn=$3 bt=$4 fr=$5 sd=$6; shift 6
  python benchmarks/bench_degrade_grid.py --in-process --cells-cache /tmp/attitude-cache --methods auto --skip-clean --peers \
    --seed $sd --datasets $ds --gains $gn --betas $bt --noise high --max-frames $fr --out-dir /tmp/attitude/grid/$out "$@" 2>&1 | grep "ATE" | grep -v "^dataset" | sed "s/^/$out /"; }
for s in 1 2; do g ba1-hr1b006-s$s haze-row 1 0.06 346 $s $R; done
C=/tmp/attitude-cache/day-loop-300-g0.15-b0.06-high-seed0-rendered
echo "cpu off: $(python /tmp/attitude/cpu.py $C /work/cache/synthetic/day-loop-seed0-full 300 2>&1 | grep ATE)"
echo "cpu ba1: $(python /tmp/attitude/cpu.py $C /work/cache/synthetic/day-loop-seed0-full 300 tracking.vertical_estimate=true mapping.attitude_prior=true 2>&1 | grep ATE)"
echo "cpu trk: $(python /tmp/attitude/cpu.py $C /work/cache/synthetic/day-loop-seed0-full 300 tracking.vertical_estimate=true mapping.attitude_prior=true tracking.vertical_track_prior=true 2>&1 | grep ATE)"
