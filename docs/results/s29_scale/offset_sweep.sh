#!/bin/bash
# s29-scale: the KITTI lit hazy cells (seeds given) through s28's diag.py with both disparity offsets moved by
# DELTA px from configs/kitti.yaml (cells 0.151, opencv 0.2); one line per cell appended to OUT.
# usage: offset_sweep.sh OUT DELTA SEED...   (CANOPY_CACHE_DIR: where the grid runner cached the cells)
repo=$(cd "$(dirname "$0")/../../.." && pwd); cd "$repo"; export PYTHONPATH="$repo"
out=$1; d=$2; shift 2
cells=$(python -c "print(round(0.151 + $d, 4))"); orb=$(python -c "print(round(0.2 + $d, 4))")
for s in "$@"; do for n in low high; do
  c="${CANOPY_CACHE_DIR:-cache}/degraded/kitti-all-g1-b0.06-$n-seed$s-stereo-sky"
  r=$(python docs/results/s28_travel/diag.py "$c" disparity_offset_cells_px=$cells disparity_offset_px=$orb 2>/dev/null | tail -1)
  echo "$(basename "$c") delta $d $r" >> "$out"
done; done
