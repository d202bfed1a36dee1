#!/usr/bin/env python
"""Thread CPU per image of CellExtractor(kitti params, responses=False) on KITTI images, plus a
cProfile of the same calls (s15-extract).

    PYTHONPATH=$PWD python docs/results/s15_extract/profile_extract.py --n 20 [--right] [--profile]
"""
from __future__ import annotations

import argparse
import cProfile
import pstats
import time

import cv2
import numpy as np

from canopy.config import load_run_config
from canopy.frontend.cell_extractor import CellExtractor
from canopy.sources import open_source


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--dataset", default="kitti")
    ap.add_argument("--n", type=int, default=20)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--right", action="store_true")
    ap.add_argument("--profile", action="store_true")
    ap.add_argument("--cv-threads", type=int, default=-1)
    a = ap.parse_args()
    if a.cv_threads >= 0:
        cv2.setNumThreads(a.cv_threads)
    tp = load_run_config(a.dataset).tracking
    ex = CellExtractor(tp, responses=False)
    src = open_source(a.dataset, max_frames=a.n)
    imgs = [(src.frame(i).right if a.right else src.frame(i).left) for i in range(min(a.n, len(src)))]
    ex.extract(imgs[0])
    ts, ps = [], []
    for _ in range(a.reps):
        for img in imgs:
            t0, p0 = time.thread_time(), time.process_time()
            ex.extract(img)
            ts.append(time.thread_time() - t0)
            ps.append(time.process_time() - p0)
    print(f"{a.dataset}: {len(imgs)} images x {a.reps}: thread CPU p50 {np.median(ts) * 1e3:.2f} ms mean "
          f"{np.mean(ts) * 1e3:.2f}; process CPU p50 {np.median(ps) * 1e3:.2f} ms")
    if a.profile:
        pr = cProfile.Profile(time.thread_time)
        pr.enable()
        for img in imgs:
            ex.extract(img)
        pr.disable()
        st = pstats.Stats(pr)
        st.sort_stats("tottime").print_stats(70)


if __name__ == "__main__":
    main()
