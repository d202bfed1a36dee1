# s33: clean KITTI with a truncated SAD (TRUNC grey levels, 0 = shipped): the whole run, 60 % of the matches
# above 40 px dropped (seeds 0-2), and the high- / low-contrast 63 % kept (docs/notes/s33-verdict.md §1).
#   bash docs/results/s33_window/clean_subsets.sh "0 8 16 32" [tracking.x=v]
cd "$(dirname "$0")/../../.."
export CANOPY_CACHE_DIR=${CANOPY_CACHE_DIR:-/work/cache} PYTHONPATH=$PWD
S=docs/results/s32_oracle W=docs/results/s33_window
sets=(); for x in "${@:2}"; do sets+=(--set "$x"); done
for T in $1; do
  export TRUNC=$T
  echo "T=$T $(python $W/with_patch.py truncated_sad $S/cell_run.py clean "${@:2}" 2>/dev/null | tail -1)"
  for s in 0 1 2; do
    echo "T=$T near-dropped seed $s $(python $W/with_patch.py truncated_sad $S/subsample_stereo.py --drop 0.6 --near-only 40 --seed $s "${sets[@]}" 2>/dev/null | tail -1)"
  done
  for c in high low; do
    echo "T=$T keep $c-contrast $(python $W/with_patch.py truncated_sad $S/subsample_stereo.py --drop 0.37 --keep-contrast $c "${sets[@]}" 2>/dev/null | tail -1)"
  done
done
