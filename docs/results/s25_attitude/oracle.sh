cd /work/wt/attitude
export CANOPY_CACHE_DIR=/work/cache PYTHONPATH=/work/wt/attitude
C=/tmp/attitude-cache
run() { # tag path clean frames extra...
  tag=$1; shift; echo "=== $tag"; python benchmarks/diagnose_pitch.py --no-counterfactuals --path "$@" 2>&1 | grep -v Warn; }
for mode in "base" "0.2" "1.0"; do
  if [ $mode = base ]; then X=""; else X="--oracle-up $mode"; fi
  for s in 0 1 2; do
    run "$mode dl-haze s$s" $C/day-loop-300-g0.15-b0.06-high-seed$s-rendered --clean /work/cache/synthetic/day-loop-seed0-full --max-frames 300 $X
  done
  for s in 0 1 2; do
    run "$mode dr-haze s$s" $C/dark-rows-150-g1-b0.06-high-seed$s-rendered --clean /work/cache/synthetic/dark-rows-seed0-full --max-frames 150 $X
  done
  run "$mode dl-clean" /work/cache/synthetic/day-loop-seed0-full --clean /work/cache/synthetic/day-loop-seed0-full --max-frames 300 $X
done
