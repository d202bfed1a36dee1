cd /work/wt/attitude
export CANOPY_CACHE_DIR=/work/cache PYTHONPATH=/work/wt/attitude
for s in 1 2; do
python benchmarks/bench_degrade_grid.py --in-process --cells-cache /tmp/attitude-cache --methods auto --skip-clean --seed $s --datasets day-loop --gains 0.15 --betas 0.06 --noise high --max-frames 300 --out-dir /tmp/attitude/base-dl-s$s
done
for s in 0 1 2; do
python benchmarks/bench_degrade_grid.py --in-process --cells-cache /tmp/attitude-cache --methods auto --skip-clean --seed $s --datasets dark-rows --gains 1 --betas 0.06 --noise high --max-frames 150 --out-dir /tmp/attitude/base-dr-s$s
done
