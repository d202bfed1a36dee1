# s33: the six KITTI bar cells x 7 noise draws (CELLS to choose, RUNNER for a patch, settings as arguments):
#   TRUNC=16 RUNNER="docs/results/s33_window/with_patch.py truncated_sad docs/results/s32_oracle/cell_run.py" bash docs/results/s33_window/sweep_cells.sh
cd "$(dirname "$0")/../../.."
export CANOPY_CACHE_DIR=${CANOPY_CACHE_DIR:-/work/cache} PYTHONPATH=$PWD
for c in ${CELLS:-g1-b0-high g0.15-b0-high g0.15-b0-low g1-b0.06-high g1-b0.06-low g1-b0-low}; do
  bash docs/results/s32_oracle/sweep.sh "$CANOPY_CACHE_DIR/degraded/kitti-all-$c-seed{s}$(case $c in *b0.0*) echo -stereo-sky;; esac)" "0 1 2 3 4 5 6" "$@" 2>/dev/null
done
