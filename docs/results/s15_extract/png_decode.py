#!/usr/bin/env python
"""KITTI PNG decoding, alternating image by image (thread CPU p50 per image): cv2.imread(GRAYSCALE)
as canopy.sources.base.read_grey does, cv2.imdecode of the file's bytes, Pillow (s15-extract).

    PYTHONPATH=$PWD python docs/results/s15_extract/png_decode.py --reps 3
"""
from __future__ import annotations

import argparse
import glob
import time

import cv2
import numpy as np
from PIL import Image

from canopy.sources import DATA_DIR


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--reps", type=int, default=3)
    a = ap.parse_args()
    paths = sorted(glob.glob(str(DATA_DIR / "kitti06_snippet") + "/**/*.png", recursive=True))
    ways = {
        "cv2.imread GRAYSCALE": lambda p: cv2.imread(p, cv2.IMREAD_GRAYSCALE),
        "cv2.imdecode(np.fromfile) GRAYSCALE": lambda p: cv2.imdecode(np.fromfile(p, np.uint8), cv2.IMREAD_GRAYSCALE),
        "PIL.Image.open -> np.asarray": lambda p: np.asarray(Image.open(p).convert("L")),
    }
    t = {k: [] for k in ways}
    same = 0
    for _ in range(a.reps):
        for p in paths:
            outs = []
            for k, f in ways.items():
                t0 = time.thread_time()
                outs.append(f(p))
                t[k].append(time.thread_time() - t0)
            same += all(np.array_equal(outs[0], o) for o in outs[1:])
    for k, v in t.items():
        print(f"{k:38s} p50 {np.median(v) * 1e3:.2f} ms per image")
    print(f"identical pixels on {same} of {len(t['cv2.imread GRAYSCALE'])} images")


if __name__ == "__main__":
    main()
