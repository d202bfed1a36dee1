#!/usr/bin/env python
"""Stereo depth against the generator's exact depth, per stereo point, without tracking.

For every STEP-th frame of a generated sequence: the tracker's own left features and stereo
matches (``Tracker._left_and_stereo`` with the synthetic config, plus ``--set`` overrides), the
contour test's flags (default ContourParams, and "disparity steps only"), and the exact depth
(``mav0/depth0``) at the keypoint's pixel and its 5x5 neighbourhood (min / max: a silhouette has
both). Writes one row per stereo point to an ``.npz`` and prints the relative depth error by
segment (row / turn), flag, near / far and image half.

    PYTHONPATH=$PWD CANOPY_CACHE_DIR=/work/cache python docs/results/s12_drift/depth_bias.py \
        /work/cache/synthetic/day-loop-seed0-full 4 /tmp/s12drift/depth_bias.npz
"""
from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))

from canopy.config import load_run_config, parse_setting, with_settings  # noqa: E402
from canopy.frontend import Tracker  # noqa: E402
from canopy.frontend.stereo_silhouette import ContourParams, SilhouetteDetector  # noqa: E402
from canopy.sources import open_source  # noqa: E402

# the day-loop's segments (docs/notes/s7-drift.md §1): rows 0-303, 506-810; turns between
SEGMENTS = ((0, 303, "row 1"), (303, 506, "turn 1"), (506, 810, "row 2"), (810, 1014, "turn 2"))


def collect(path: str, step: int, sets: list[str]) -> dict:
    cfg = with_settings(load_run_config("synthetic"), [parse_setting(s) for s in sets])
    tp = replace(cfg.tracking, contour_enabled=False)
    src = open_source("euroc", path)
    tracker = Tracker(src.calibration, tp)
    det = SilhouetteDetector(ContourParams.from_tracking(replace(tp, contour_enabled=True)))
    det_steps = SilhouetteDetector(ContourParams.from_tracking(replace(tp, contour_enabled=True,
                                                                       contour_unmatched_is_contour=False)))
    depth_files = sorted((Path(path) / "mav0" / "depth0" / "data").iterdir())
    rows = []
    for i in range(0, len(src), step):
        frame = src.frame(i)
        left, stereo, _ = tracker._left_and_stereo(frame, (None, None, 0), None, {})
        if hasattr(stereo, "result"):
            stereo = stereo.result()
        idx = np.flatnonzero(stereo.valid)
        if len(idx) == 0:
            continue
        uv = left.uv[idx].astype(np.float64)
        on = det(frame.left, frame.right, uv, left.octave[idx], tp.scale_factor)
        on_s = det_steps(frame.left, frame.right, uv, left.octave[idx], tp.scale_factor)
        exact = cv2.imread(str(depth_files[i]), cv2.IMREAD_UNCHANGED).astype(np.float32) / 1000.0
        exact[exact <= 0] = np.inf  # sky
        h, w = exact.shape
        x = np.clip(np.round(uv[:, 0]).astype(int), 0, w - 1)
        y = np.clip(np.round(uv[:, 1]).astype(int), 0, h - 1)
        lo = cv2.erode(exact, np.ones((5, 5), np.uint8))    # nearest within 5x5
        hi = cv2.dilate(exact, np.ones((5, 5), np.uint8))   # farthest within 5x5
        rows.append(np.column_stack([np.full(len(idx), i), uv, left.octave[idx], stereo.depth[idx],
                                     exact[y, x], lo[y, x], hi[y, x], on, on_s]))
    return {"rows": np.concatenate(rows)}


def summarise(r: np.ndarray) -> None:
    f, u, v, octv, z, zt, zlo, zhi, on, on_s = r.T
    err = z / zt - 1.0                      # relative depth error at the pixel (sky: -1)
    surface = np.isfinite(zhi) & (zhi < 1.05 * zlo)
    print(f"{len(r)} stereo points; sky at the pixel {np.mean(~np.isfinite(zt)):.1%}, "
          f"surface (5x5 depth within 5 %) {surface.mean():.1%}")
    print("segment | group | n | share | median rel err | |err|>10 % | upper-half share of |err|>10 %")
    for a, b, name in SEGMENTS:
        s = (f >= a) & (f < b)
        groups = (("all", s), ("flagged", s & (on > 0)), ("steps", s & (on_s > 0)),
                  ("unflagged", s & (on == 0)), ("near <4.4 m", s & (z < 4.4)), ("far >=4.4 m", s & (z >= 4.4)),
                  ("surface", s & surface), ("not surface", s & ~surface))
        for g, m in groups:
            if not m.any():
                continue
            e = err[m]
            bad = np.abs(e) > 0.10
            up = np.mean(v[m][bad] < 239.5) if bad.any() else np.nan
            print(f"{name:7s} | {g:12s} | {m.sum():6d} | {m.sum() / s.sum():5.1%} | {np.median(e):+.4f} | "
                  f"{bad.mean():5.1%} | {up:.2f}")


if __name__ == "__main__":
    if len(sys.argv) < 4:
        raise SystemExit(__doc__)
    out = collect(sys.argv[1], int(sys.argv[2]), sys.argv[4:])
    np.savez(sys.argv[3], **out)
    summarise(out["rows"])
