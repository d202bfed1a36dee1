#!/bin/bash
# s16-darkhaze: preset grid cells (in process, auto, no ORB-SLAM3 columns) for one variant. Usage:
#   run_preset.sh NAME DATASET MAX_FRAMES "GAINS" "BETAS" "SEEDS" [--set ...]
cd "$(dirname "$0")/../../.."
export CANOPY_CACHE_DIR=/work/cache PYTHONPATH=$PWD
name=$1; d=$2; mf=$3; gains=$4; betas=$5; seeds=$6; shift 6
for s in $seeds; do
  python benchmarks/bench_degrade_grid.py --in-process --cells-cache /work/cache/degraded_darkhaze --datasets $d \
    --gains $gains --betas $betas --noise high --max-frames $mf --methods auto --peers --skip-clean --seed $s \
    --out-dir /tmp/dh/${name}_${d}_s$s "$@" > /tmp/dh/${name}_${d}_s$s.log 2>&1
  grep "ATE\|tracked" /tmp/dh/${name}_${d}_s$s.log | grep $d | sed "s/^/$name s$s /"
done
