#!/bin/bash
# s16-darkhaze: s13-haze's per-frame diagnosis (ATE = the grid's, plus per-frame rotation error rms,
# inliers, far points) on KITTI cells over seeds for one variant. Usage:
#   diag_kitti.sh NAME "CELLS" "SEEDS" [--set ...]     (CELLS e.g. "g1-b0.06-high g0.15-b0.06-high")
cd "$(dirname "$0")/../../.."
export CANOPY_CACHE_DIR=/work/cache PYTHONPATH=$PWD
name=$1; cells=$2; seeds=$3; shift 3
for c in $cells; do for s in $seeds; do
  python docs/results/s13_haze/diag_frames.py /work/cache/degraded_darkhaze/kitti-all-$c-seed$s --quiet "$@" 2>&1 | grep SUMMARY | sed "s/^/$name /"
done; done
