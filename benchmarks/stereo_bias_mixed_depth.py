#!/usr/bin/env python
"""Split ``stereo_bias.py --ref clean --out M.npy`` matches of a preset by mixed- vs single-depth patch (s22).

A match is "mixed-depth" when the renderer's exact depth in the 15x15 around its keypoint (level-0 pixels)
spans more than 20 %: haze lowers the far surface's contrast by t = exp(-beta d) and keeps the near one's,
so such a patch matches at the nearer disparity (docs/notes/s22-hazepaint.md).

    PYTHONPATH=$PWD python benchmarks/stereo_bias_mixed_depth.py --matches m.npy \\
        --clean /work/cache/synthetic/day-loop-seed0-full --frames 300
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from canopy.sources import open_source  # noqa: E402
from tools.degrade_sequence import _euroc_rectification, rectify_nearest  # noqa: E402

WINDOW = 15
SPAN = 1.2


def mixed_depth(A: np.ndarray, clean: Path, frames: int | None) -> np.ndarray:
    """Per match (rows of stereo_bias's array: frame, octave, d, d_ref, z, u, v): mixed-depth patch?"""
    src = open_source("euroc", clean, max_frames=frames)
    _, forward = _euroc_rectification(src)
    out = np.zeros(len(A), bool)
    k = np.ones((WINDOW, WINDOW))
    for f in np.unique(A[:, 0]).astype(int):
        m = A[:, 0] == f
        raw = cv2.imread(str(clean / "mav0" / "depth0" / "data" / src.left_paths[f].name), cv2.IMREAD_UNCHANGED)
        z = rectify_nearest(raw, forward[0]).astype(np.float32) / 1000.0
        lz = np.log(np.where(z > 0, z, 200.0))
        span = cv2.dilate(lz, k) - cv2.erode(lz, k)
        u = np.clip(np.rint(A[m, 5]).astype(int), 0, z.shape[1] - 1)
        v = np.clip(np.rint(A[m, 6]).astype(int), 0, z.shape[0] - 1)
        out[m] = span[v, u] > np.log(SPAN)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--matches", required=True)
    ap.add_argument("--clean", required=True)
    ap.add_argument("--frames", type=int, default=None)
    args = ap.parse_args()
    A = np.load(args.matches)
    clean = Path(args.clean)
    bf = open_source("euroc", clean, max_frames=1).calibration.bf
    mixed = mixed_depth(A, clean, args.frames)
    err = A[:, 2] - A[:, 3]
    ok = np.isfinite(err) & (A[:, 3] > 0)
    z_ref = bf / np.where(A[:, 3] > 0, A[:, 3], np.nan)
    for name, sel in (("mixed-depth", mixed), ("single-depth", ~mixed)):
        print(f"{name} patches: median signed error px (n, fraction > 2 px off)")
        for a, b in ((0, 5), (5, 10), (10, 20), (20, 40), (40, np.inf)):
            m = ok & sel & (z_ref >= a) & (z_ref < b)
            if m.sum() > 20:
                print(f"  [{a}, {b}) m: {np.median(err[m]):+.4f} (n={m.sum()}, {(np.abs(err[m]) > 2).mean():.3f})")
        for o in range(int(A[:, 1].max()) + 1):
            m = ok & sel & (A[:, 1] == o)
            if m.sum() > 20:
                print(f"  octave {o}: {np.median(err[m]):+.4f} (n={m.sum()})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
