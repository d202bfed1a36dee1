"""s13-haze diagnostics' shared per-frame step (far_loss.py, far_stereo.py): every ``step``-th frame
of a degraded KITTI cell enhanced and extracted as the tracking actor does, its stereo matches, and
the clean snippet's SGBM disparity at each left keypoint (the depth reference)."""
import numpy as np

from benchmarks.bench_enhance_diagnose import actor_fast, enhance_pair
from canopy.degrade import disparity_sgbm
from canopy.enhance import make_enhancer
from canopy.frontend import Tracker
from canopy.frontend.stereo import match_stereo
from canopy.sources import BUNDLED_DATA, open_source


def frames_against_clean(cell: str, cfg, tp, step: int = 10):
    """Yield (frame index, tracker, left features, right features, stereo matches, clean disparity
    at the left keypoints) for ``cell`` (a degraded KITTI folder) with tracking params ``tp``."""
    src, clean = open_source("kitti", cell), open_source("kitti", BUNDLED_DATA["kitti"])
    enh = make_enhancer(cfg.enhancement)
    tr = Tracker(src.calibration, tp)
    for i in range(0, len(src), step):
        fr, c = src.frame(i), clean.frame(i)
        le, re, info = enhance_pair(enh, fr.left, fr.right)
        kw = actor_fast(cfg.enhancement, info, le, tp.n_features)
        fast = (kw.get("fast_threshold"), kw.get("fast_fallback"), kw.get("fast_min_keypoints", 0))
        fl, frr = tr.extractor.extract(le, *fast), tr.extractor_right.extract(re, *fast)
        st = match_stereo(fl, frr, le, re, tr.calib, tp)
        ref = disparity_sgbm(c.left, c.right).astype(float)
        h, w = ref.shape
        d = ref[np.clip(np.rint(fl.uv[:, 1]).astype(int), 0, h - 1), np.clip(np.rint(fl.uv[:, 0]).astype(int), 0, w - 1)]
        yield i, tr, fl, frr, st, d
