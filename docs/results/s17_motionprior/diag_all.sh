#!/bin/bash
# per-frame rotation / translation error (s13-haze's diag_frames.py) for main and the prior 0.1 deg / 2 cm,
# KITTI g0.15-b0.06-high and g1-b0.06-high, noise seeds 0-4: SUMMARY lines
cell() { [ $2 -le 2 ] && echo /work/cache/degraded/kitti-all-$1-seed$2 || echo /work/cache/degraded_kittihaze/kitti-all-$1-seed$2; }
for c in $CELLS; do for s in 0 1 2 3 4; do
  python docs/results/s13_haze/diag_frames.py $(cell $c $s) 2>&1 | grep SUMMARY
  python docs/results/s13_haze/diag_frames.py $(cell $c $s) --set tracking.motion_prior_sigma_deg=0.1 --set tracking.motion_prior_sigma_m=0.02 2>&1 | grep SUMMARY
done; done
