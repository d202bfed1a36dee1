#!/usr/bin/env python
"""Stereo points of a generated (or degraded) sequence against the renderer's exact depth.

Every STEP-th of the first N frames: the tracker's own left features and stereo matches
(``Tracker._left_and_stereo``, synthetic config + ``--set`` overrides; the frames as given, i.e.
no enhancement), and the exact depth (``mav0/depth0``) at the keypoint. Prints, per run: stereo
points per frame, share whose depth is > 10 % off, median |disparity error| (px) of the points on a
surface (exact depth within 5 % over 5x5), split near / far (exact depth < / >= 8 m).

    PYTHONPATH=$PWD CANOPY_CACHE_DIR=/work/cache python docs/results/s13_presets/stereo_truth.py \
        /work/cache/degraded/day-loop-300-g1-b0.06-high-seed0-rendered 300 5 [--set tracking.X=Y ...]
"""
from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))

from canopy.config import load_run_config, parse_setting, with_settings  # noqa: E402
from canopy.frontend import Tracker  # noqa: E402
from canopy.sources import open_source  # noqa: E402


def collect(path: str, n: int, step: int, sets: list[str]) -> np.ndarray:
    cfg = with_settings(load_run_config("synthetic"), [parse_setting(s) for s in sets])
    src = open_source("euroc", path)
    tracker = Tracker(src.calibration, cfg.tracking)
    fb = src.calibration.fx * src.calibration.baseline
    depth_files = sorted((Path(path) / "mav0" / "depth0" / "data").iterdir())
    rows = []
    for i in range(0, min(n, len(src)), step):
        frame = src.frame(i)
        left, stereo, _ = tracker._left_and_stereo(frame, (None, None, 0), None, {})
        if hasattr(stereo, "result"):
            stereo = stereo.result()
        idx = np.flatnonzero(stereo.valid)
        exact = cv2.imread(str(depth_files[i]), cv2.IMREAD_UNCHANGED).astype(np.float32) / 1000.0
        exact[exact <= 0] = np.inf
        h, w = exact.shape
        uv = left.uv[idx].astype(np.float64)
        x = np.clip(np.round(uv[:, 0]).astype(int), 0, w - 1)
        y = np.clip(np.round(uv[:, 1]).astype(int), 0, h - 1)
        lo = cv2.erode(exact, np.ones((5, 5), np.uint8))
        hi = cv2.dilate(exact, np.ones((5, 5), np.uint8))
        rows.append(np.column_stack([np.full(len(idx), i), np.full(len(idx), len(left.uv)), left.octave[idx],
                                     stereo.depth[idx], exact[y, x], lo[y, x], hi[y, x], uv[:, 1]]))
    return np.concatenate(rows), fb


def summarise(name: str, r: np.ndarray, fb: float) -> None:
    f, nl, octv, z, zt, zlo, zhi, v = r.T
    frames = np.unique(f)
    err = z / zt - 1.0
    surface = np.isfinite(zhi) & (zhi < 1.05 * zlo)
    dd = np.abs(fb / z - fb / np.where(np.isfinite(zt), zt, np.inf))
    near, far = surface & (zt < 8), surface & (zt >= 8)
    print(f"{name}: {len(frames)} frames, stereo/frame {len(r) / len(frames):.0f}, "
          f">10% off {np.mean(np.abs(err) > 0.1):.1%}, surface {surface.mean():.1%}, "
          f"surface >10% off {np.mean(np.abs(err[surface]) > 0.1):.1%}, "
          f"|dd| med near {np.median(dd[near]):.3f} px (n {near.sum() / len(frames):.0f}/fr), "
          f"far {np.median(dd[far]) if far.any() else np.nan:.3f} px (n {far.sum() / len(frames):.0f}/fr), "
          f"surface |dd|>1px {np.mean(dd[surface] > 1):.1%}")
    # signed disparity error (estimated - exact, px) of the surface points per 80-px image band, top to
    # bottom: a bias that changes with the image row tilts the map (pitch)
    sd = fb / z - fb / np.where(np.isfinite(zt), zt, np.inf)
    bands = [f"{np.median(sd[m]):+.3f}({m.sum()})" if m.sum() > 20 else "   -   "
             for m in (surface & (v >= a) & (v < a + 80) for a in range(0, 480, 80))]
    print("   signed dd median per 80-px band (n):", " ".join(bands))


if __name__ == "__main__":
    if len(sys.argv) < 4:
        raise SystemExit(__doc__)
    sets = [a for a in sys.argv[4:] if a != "--set"]
    r, fb = collect(sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sets)
    summarise(Path(sys.argv[1]).name + (" " + " ".join(sets) if sets else ""), r, fb)
