#!/bin/bash
# s29-scale: preset cells (gains GAINS, default 0.15 0.06; beta 0 and 0.06; high noise) per seed with --set overrides; JSON under OUT/TAG/
# usage: run_dl.sh TAG DATASET FRAMES SEEDS... -- [--set ...]
repo=$(cd "$(dirname "$0")/../../.." && pwd); cd "$repo"; export PYTHONPATH="$repo" CANOPY_CACHE_DIR=${CANOPY_CACHE_DIR:-/work/cache}
tag=$1; ds=$2; nf=$3; shift 3
seeds=(); while [ $# -gt 0 ] && [ "$1" != "--" ]; do seeds+=("$1"); shift; done; shift
for s in "${seeds[@]}"; do
  python benchmarks/bench_degrade_grid.py --in-process --cells-cache $CANOPY_CACHE_DIR/degraded --datasets $ds \
    --gains ${GAINS:-0.15 0.06} --betas 0 0.06 --noise high --methods auto --skip-clean --seed $s --max-frames $nf \
    --out-dir ${OUT:-/tmp/s29}/$tag/${ds}_s$s "$@" > ${OUT:-/tmp/s29}/$tag.${ds}_s$s.log 2>&1
done
