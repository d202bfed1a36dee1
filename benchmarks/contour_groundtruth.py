#!/usr/bin/env python
"""How well does the occluding-contour test (canopy.frontend.stereo_silhouette) find the stereo
points whose depth is wrong? Against a generated sequence's exact depth (mav0/depth0).

For the given frames: ORB + stereo matching with the dataset's shipped tracking config, the depth
error of every stereo point against the generator's depth at its pixel (sky: wrong), then for
each contour setting the fraction flagged, the fraction of wrong (> 10 %) and of good (< 3 %)
points flagged, and the wrong ones among those kept.

    PYTHONPATH=$PWD python benchmarks/contour_groundtruth.py \
        --path /work/cache/synthetic/day-loop-seed0-full --frames 0,100,300,320,340,400,600,700,820,900
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from canopy.config import load_run_config  # noqa: E402
from canopy.frontend.features import OrbExtractor  # noqa: E402
from canopy.frontend.stereo import match_stereo  # noqa: E402
from canopy.frontend.stereo_silhouette import ContourParams, SilhouetteDetector  # noqa: E402
from canopy.sources import open_source  # noqa: E402
from shared.errors import InputError  # noqa: E402

VARIANTS = [dict(), dict(ratio=0.15), dict(octave_scaled=True), dict(window_px=5.0), dict(ratio=0.05)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--path", required=True, help="generated sequence folder (with mav0/depth0)")
    ap.add_argument("--frames", default="0,100,300,320,340,400,600,700,820,900")
    args = ap.parse_args()
    root = Path(args.path) / "mav0"
    if not (root / "depth0" / "data").is_dir():
        raise InputError(root / "depth0", "no exact depth here: generate the sequence with canopy.synthetic")
    tp = load_run_config("synthetic").tracking
    calib = open_source("euroc", args.path).calibration
    c0, c1, dn = (sorted((root / c / "data").iterdir()) for c in ("cam0", "cam1", "depth0"))
    ex, exr = OrbExtractor(tp), OrbExtractor(tp)
    data = []
    for i in [int(f) for f in args.frames.split(",")]:
        left, right = cv2.imread(str(c0[i]), 0), cv2.imread(str(c1[i]), 0)
        depth = cv2.imread(str(dn[i]), cv2.IMREAD_UNCHANGED).astype(np.float32) / 1000.0  # mm, 0 = sky
        lf, rf = ex.extract(left), exr.extract(right)
        st = match_stereo(lf, rf, left, right, calib, tp)
        v = np.flatnonzero(st.valid)
        x, y = np.round(lf.uv[v, 0]).astype(int), np.round(lf.uv[v, 1]).astype(int)
        z = depth[y, x]
        err = np.where(z > 0, np.abs(st.depth[v] / np.maximum(z, 1e-6) - 1), np.inf)
        data.append((left, right, lf.uv[v].astype(np.float64), lf.octave[v], err))
    err = np.concatenate([d[4] for d in data])
    print(f"{len(err)} stereo points in {len(data)} frames: depth > 10 % off {np.mean(err > 0.1):.1%}, "
          f"within 3 % {np.mean(err < 0.03):.1%}")
    for v in VARIANTS:
        det = SilhouetteDetector(ContourParams(**v))
        fl = np.concatenate([det(left, right, uv, oc, tp.scale_factor) for left, right, uv, oc, _ in data])
        print(f"{str(v or 'shipped defaults'):40s} flagged {fl.mean():.0%}  wrong flagged {fl[err > 0.1].mean():.0%}  "
              f"good flagged {fl[err < 0.03].mean():.0%}  wrong among kept {np.mean(err[~fl] > 0.1):.1%}")


if __name__ == "__main__":
    main()
