#!/usr/bin/env python
"""s13-haze: why far keypoints get no stereo match on hazy frames. For left keypoints whose clean
SGBM depth is > 20 m (every 10th frame): is a right keypoint within 2 px of the true column (clean
disparity) on the row band and a compatible level, its Hamming distance, and how many end matched.

    CANOPY_CACHE_DIR=/work/cache PYTHONPATH=$PWD python docs/results/s13_haze/far_stereo.py <cell dir|clean>
"""
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))
from canopy.config import load_run_config  # noqa: E402
from canopy.frontend.matching import as_words, hamming_pairs  # noqa: E402
from canopy.frontend.stereo import stereo_candidates  # noqa: E402
from canopy.sources import BUNDLED_DATA  # noqa: E402
from far_frames import frames_against_clean  # noqa: E402

cfg = load_run_config("kitti")
tp = cfg.tracking
path = BUNDLED_DATA["kitti"] if sys.argv[1] == "clean" else sys.argv[1]
sf = tp.scale_factor ** np.arange(tp.n_levels)
n_far = n_has = n_match = 0
hd_true, hd_best = [], []
for i, tr, fl, frr, st, d in frames_against_clean(path, cfg, tp):
    bf = tr.calib.bf
    far = (d > 0) & (d < bf / 20.0)
    qi, rj, _ = stereo_candidates(fl, frr, tp.row_tolerance * sf[fl.octave], tp.octave_tolerance)
    dist = hamming_pairs(as_words(fl.descriptors), as_words(frr.descriptors), qi, rj)
    true_col = fl.uv[qi, 0] - d[qi]
    near_true = np.abs(frr.uv[rj, 0] - true_col) <= 2.0
    for k in np.flatnonzero(far):
        n_far += 1
        m = (qi == k)
        if (m & near_true).any():
            n_has += 1
            hd_true.append(int(dist[m & near_true].min()))
        if m.any():
            hd_best.append(int(dist[m].min()))
        n_match += int(st.valid[k])
ht = np.array(hd_true)
print(Path(path).name, f"far kps {n_far}, with a right kp at the true column {n_has} ({n_has / max(n_far, 1):.2f}), "
      f"stereo matched {n_match} ({n_match / max(n_far, 1):.2f}); Hamming to the true right kp: median {np.median(ht):.0f}, "
      f"<=75 {np.mean(ht <= 75):.2f}, <=100 {np.mean(ht <= 100):.2f}")
