#!/bin/bash
# s28-travel: every cached KITTI lit hazy cell (g1-b0.06-*, each seed the grid runner made) in process,
# one line per cell appended to OUT: its ATE, Sim(3) ATE and scale, and the per-frame step error.
# usage: matrix.sh OUT [tracking_field=value ...]   (CANOPY_CACHE_DIR: where the grid runner cached the cells)
here=$(cd "$(dirname "$0")" && pwd)
repo=$(cd "$here/../../.." && pwd)
cd "$repo"; export PYTHONPATH="$repo"
out=$1; shift
for c in "${CANOPY_CACHE_DIR:-cache}"/degraded/kitti-all-g1-b0.06-*; do
  r=$(python "$here/diag.py" "$c" "$@" 2>/dev/null | tail -1)
  echo "$(basename "$c") $r" >> "$out"
done
