"""Far keypoints and their stereo matches on one KITTI cell (s24-kittinoisy): per depth bin (the clean pair's
SGBM depth at the keypoint), left keypoints, stereo matches, matches within 1 px of the clean disparity and the
signed disparity error (estimate - clean SGBM) of those within 3 px, over every 5th frame.

    CANOPY_CACHE_DIR=/work/cache PYTHONPATH=$PWD python docs/results/s24_kittinoisy/far_census.py \
        --path /tmp/kittinoisy-cache/kitti-all-g1-b0.06-high-seed0-stereo-sky [--set name=value ...]
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))
from canopy.config import load_run_config, parse_value  # noqa: E402
from canopy.degrade import disparity_sgbm  # noqa: E402
from canopy.frontend import Tracker  # noqa: E402
from canopy.frontend.stereo import match_stereo  # noqa: E402
from canopy.frontend.track_health import image_noise_sigma  # noqa: E402
from canopy.sources import BUNDLED_DATA, open_source  # noqa: E402

BINS = [(0, 15), (15, 30), (30, 1e9)]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--path", required=True)
    ap.add_argument("--set", action="append", default=[])
    ap.add_argument("--step", type=int, default=5)
    a = ap.parse_args()
    cfg = load_run_config("kitti")
    tp = replace(cfg.tracking, **{k: parse_value(v) for k, v in (s.split("=", 1) for s in a.set)})
    src, clean = open_source("kitti", a.path), open_source("kitti", BUNDLED_DATA["kitti"])
    tr = Tracker(src.calibration, tp)
    bf = src.calibration.bf
    tot = np.zeros((len(BINS), 3), int)
    signed = [[] for _ in BINS]
    for i in range(0, len(src), a.step):
        f, c = src.frame(i), clean.frame(i)
        ref = disparity_sgbm(c.left, c.right).astype(np.float64)
        ns = image_noise_sigma(f.left)
        fl = tr.extractor.extract(f.left, noise_sigma=ns)
        fr = tr.extractor_right.extract(f.right, noise_sigma=image_noise_sigma(f.right))
        st = match_stereo(fl, fr, f.left, f.right, tr.calib, tp, noise_sigma=ns)
        h, w = ref.shape
        uv = np.rint(fl.uv).astype(int)
        d_ref = ref[np.clip(uv[:, 1], 0, h - 1), np.clip(uv[:, 0], 0, w - 1)]
        z_ref = np.where(d_ref > 0, bf / np.maximum(d_ref, 1e-6), np.inf)
        d_est = fl.uv[:, 0] - st.u_right
        good = st.valid & (d_ref > 0) & (np.abs(d_est - d_ref) <= 1.0)
        for b, (lo, hi) in enumerate(BINS):
            m = (z_ref >= lo) & (z_ref < hi)
            tot[b] += [m.sum(), (m & st.valid).sum(), (m & good).sum()]
            near3 = m & st.valid & (d_ref > 0) & (np.abs(d_est - d_ref) <= 3.0)
            signed[b].extend((d_est - d_ref)[near3].tolist())
    for (lo, hi), (n, s, g), e in zip(BINS, tot, signed):
        print(f"depth {lo}-{hi if hi < 1e8 else 'inf'} m: keypoints {n}, stereo {s} ({s / max(n, 1):.0%}), "
              f"within 1 px {g} ({g / max(s, 1):.0%} of stereo), signed error of those within 3 px: "
              f"median {np.median(e) if e else np.nan:+.3f} px, mean {np.mean(e) if e else np.nan:+.3f} px")


if __name__ == "__main__":
    main()
