#!/bin/bash
# s17-kittihaze: diag_frames.py SUMMARY lines for one variant over KITTI cells and seeds. Usage:
#   diag.sh NAME "CELLS" "SEEDS" [--set ...]   (cells from /work/cache/degraded, else /work/cache/degraded_kittihaze)
cd "$(dirname "$0")/../../.."
export CANOPY_CACHE_DIR=/work/cache PYTHONPATH=$PWD
name=$1; cells=$2; seeds=$3; shift 3
for c in $cells; do for s in $seeds; do
  d=/work/cache/degraded/kitti-all-$c-seed$s; [ -d $d ] || d=/work/cache/degraded_kittihaze/kitti-all-$c-seed$s
  python docs/results/s13_haze/diag_frames.py $d --quiet --out /tmp/kh_$name-$c-s$s.npz "$@" 2>&1 | grep SUMMARY | sed "s/^/$name /"
done; done
