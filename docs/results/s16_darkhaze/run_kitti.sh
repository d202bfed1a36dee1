#!/bin/bash
# s16-darkhaze: KITTI grid cells over seeds for one variant. Usage:
#   run_kitti.sh NAME "GAINS" "BETAS" "NOISE" "SEEDS" [--set ...]
# writes /tmp/dh/NAME_s<seed>/bench_degrade_grid.json (in process, auto, no ORB-SLAM3 columns)
set -e
name=$1; gains=$2; betas=$3; noise=$4; seeds=$5; shift 5
cd "$(dirname "$0")/../../.."
export CANOPY_CACHE_DIR=/work/cache PYTHONPATH=$PWD
for s in $seeds; do
  python benchmarks/bench_degrade_grid.py --in-process --cells-cache /work/cache/degraded_darkhaze --datasets kitti \
    --gains $gains --betas $betas --noise $noise --methods auto --peers --skip-clean --seed $s \
    --out-dir /tmp/dh/${name}_s$s "$@" > /tmp/dh/${name}_s$s.log 2>&1
  grep "ATE\|tracked" /tmp/dh/${name}_s$s.log | grep kitti | sed "s/^/$name s$s /"
done
