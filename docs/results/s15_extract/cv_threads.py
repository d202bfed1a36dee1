#!/usr/bin/env python
"""OpenCV's thread pool and the cell extractor (s15-extract): the left image extracted on this thread
while a worker thread extracts the right one (as the tracker does), with cv2.setNumThreads(1) and (2)
alternating pair by pair. Prints per pair: process CPU, the two threads' CPU, wall time (p50).

    PYTHONPATH=$PWD python docs/results/s15_extract/cv_threads.py --pairs 40 --reps 2
"""
from __future__ import annotations

import argparse
import time
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np

from canopy.config import load_run_config
from canopy.frontend.noisy_features import tracking_extractor
from canopy.sources import open_source


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--pairs", type=int, default=40)
    ap.add_argument("--reps", type=int, default=2)
    a = ap.parse_args()
    tp = load_run_config("kitti").tracking
    left_ex, right_ex = tracking_extractor(tp, responses=False), tracking_extractor(tp, responses=False)
    src = open_source("kitti", max_frames=a.pairs)
    pairs = [(f.left, f.right) for f in (src.frame(i) for i in range(len(src)))]
    pool = ThreadPoolExecutor(max_workers=1)

    def right_job(img):
        t = time.thread_time()
        right_ex.extract(img)
        return time.thread_time() - t

    res = {1: [], 2: []}
    for _ in range(a.reps):
        for left, right in pairs:
            for n in (1, 2):
                cv2.setNumThreads(n)
                w0, p0, t0 = time.perf_counter(), time.process_time(), time.thread_time()
                fut = pool.submit(right_job, right)
                left_ex.extract(left)
                t_left = time.thread_time() - t0
                t_right = fut.result()
                res[n].append((time.process_time() - p0, t_left, t_right, time.perf_counter() - w0))
    for n, rows in res.items():
        r = np.median(np.array(rows), axis=0) * 1e3
        print(f"cv2.setNumThreads({n}): p50 per pair: process CPU {r[0]:.2f} ms, left thread {r[1]:.2f}, "
              f"right thread {r[2]:.2f}, other threads {r[0] - r[1] - r[2]:.2f}, wall {r[3]:.2f} ms")


if __name__ == "__main__":
    main()
