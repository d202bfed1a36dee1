#!/usr/bin/env python
"""Milliseconds per image of the two tracking extractors (``tracking.extractor``: opencv | cells).

Each image of the KITTI 06 and EuRoC V1_01 snippets (left images) goes through cv2.ORB with grid
bucketing (``OrbExtractor``) and the ORB-SLAM-style cell extractor (``CellExtractor``), alternating
image by image so that both see the same machine load; the dataset's tracking config sets the
feature budget. Prints one table (wall ms p50 / mean, process CPU ms mean, keypoints) and writes
JSON. CPU time counts OpenCV's worker threads too. Say what the load was (``uptime``) when quoting.

    PYTHONPATH=$PWD python benchmarks/bench_extractors.py [--frames 30] [--out docs/results/bench_extractors.json]
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from canopy.config import load_run_config  # noqa: E402
from canopy.frontend.cell_extractor import CellExtractor  # noqa: E402
from canopy.frontend.features import OrbExtractor  # noqa: E402
from canopy.report import write_json  # noqa: E402
from canopy.sources import open_source  # noqa: E402


def bench(dataset: str, frames: int, repeats: int) -> dict:
    tp = load_run_config(dataset).tracking
    src = open_source(dataset, None, max_frames=frames)
    images = [src.frame(i).left for i in range(len(src))]
    extractors = {"opencv": OrbExtractor(replace(tp, extractor="opencv")),
                  "cells": CellExtractor(replace(tp, extractor="cells"))}
    for ex in extractors.values():  # warm-up (allocations, OpenCV's thread pool)
        ex.extract(images[0])
    wall = {k: [] for k in extractors}
    cpu = {k: [] for k in extractors}
    count = {k: [] for k in extractors}
    for _ in range(repeats):
        for img in images:
            for name, ex in extractors.items():
                c0, t0 = time.process_time(), time.perf_counter()
                f = ex.extract(img)
                wall[name].append((time.perf_counter() - t0) * 1e3)
                cpu[name].append((time.process_time() - c0) * 1e3)
                count[name].append(len(f))
    h, w = images[0].shape
    return {name: {"wall_ms_p50": float(np.median(wall[name])), "wall_ms_mean": float(np.mean(wall[name])),
                   "cpu_ms_mean": float(np.mean(cpu[name])), "keypoints_mean": float(np.mean(count[name])),
                   "images": len(wall[name]), "image_size": [int(w), int(h)], "n_features": tp.n_features}
            for name in extractors}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--datasets", nargs="*", default=["kitti", "euroc"])
    ap.add_argument("--frames", type=int, default=30, help="images per dataset")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--out", default=str(ROOT / "docs" / "results" / "bench_extractors.json"))
    args = ap.parse_args(argv)
    load = os.getloadavg()
    rows = {d: bench(d, args.frames, args.repeats) for d in args.datasets}
    print(f"load average {load[0]:.1f} {load[1]:.1f} {load[2]:.1f} on {os.cpu_count()} cores (timings are loaded "
          f"when the load exceeds the cores)")
    print(f"{'dataset':<8} {'extractor':<8} {'size':>10} {'features':>8} {'wall p50':>9} {'wall mean':>10} "
          f"{'CPU mean':>9} {'keypoints':>9}")
    for d, r in rows.items():
        for name, v in r.items():
            print(f"{d:<8} {name:<8} {'x'.join(map(str, v['image_size'])):>10} {v['n_features']:>8} "
                  f"{v['wall_ms_p50']:>7.1f}ms {v['wall_ms_mean']:>8.1f}ms {v['cpu_ms_mean']:>7.1f}ms "
                  f"{v['keypoints_mean']:>9.0f}")
        print(f"{d:<8} cells / opencv wall p50: {r['cells']['wall_ms_p50'] / r['opencv']['wall_ms_p50']:.2f}x")
    out = write_json(args.out, {"benchmark": "bench_extractors", "load_average": list(load),
                                "cores": os.cpu_count(), "frames": args.frames, "repeats": args.repeats,
                                "results": rows})
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
