#!/usr/bin/env python
"""The cell extractor of this checkout against another checkout's, image by image (issue 8: speed).

Loads ``canopy/frontend/cell_extractor.py`` from ``--base`` (another checkout, e.g. a
``git archive`` of the branch point) beside this checkout's, runs both on every left and right
image of the KITTI 06 snippet (KITTI's tracking config), alternating image by image so that a
shared machine's load hits both alike, and prints the tracking-thread CPU per image
(``time.thread_time``, p50) and the process CPU per image (``time.process_time``: with the
helper threads of OpenBLAS and OpenCV) of each, their ratios, and on how many images the two outputs
(keypoints, octaves, responses, descriptors) are identical.

    git archive <base-commit> | tar -x -C /tmp/base
    PYTHONPATH=$PWD python benchmarks/ab_cell_extractor.py --base /tmp/base --reps 2
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from ab_checkout import load_module  # noqa: E402  (a sibling: benchmarks/ is sys.path[0])

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from canopy.config import load_run_config  # noqa: E402
from canopy.sources import open_source  # noqa: E402

FIELDS = ("uv", "octave", "response", "descriptors")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--base", type=Path, required=True, help="the other checkout's root")
    ap.add_argument("--dataset", default="kitti")
    ap.add_argument("--reps", type=int, default=1)
    ap.add_argument("--no-responses", action="store_true",
                    help="this checkout's extractor as the tracker builds it (responses=False): responses not compared")
    a = ap.parse_args()
    rel = Path("canopy/frontend/cell_extractor.py")
    base = load_module(a.base / rel, "base_cell_extractor")
    this = load_module(ROOT / rel, "this_cell_extractor")
    tp = load_run_config(a.dataset).tracking
    ex_this = this.CellExtractor(tp, responses=False) if a.no_responses else this.CellExtractor(tp)
    ex_base = base.CellExtractor(tp)
    if a.no_responses:  # the base as its tracker builds it too, if it has the option (s9 on)
        try:
            ex_base = base.CellExtractor(tp, responses=False)
        except TypeError:
            print("ab_cell_extractor: the base has no responses option: it computes Harris responses (~3 ms)")
    fields = tuple(f for f in FIELDS if not (a.no_responses and f == "response"))
    src = open_source(a.dataset, None)
    images = [src.frame(i).left for i in range(len(src))] + [src.frame(i).right for i in range(len(src))]
    t_base, t_this, p_base, p_this, same = [], [], [], [], 0
    for _ in range(a.reps):
        for img in images:
            t0, c0 = time.thread_time(), time.process_time()
            fb = ex_base.extract(img)
            t_base.append(time.thread_time() - t0)
            p_base.append(time.process_time() - c0)
            t0, c0 = time.thread_time(), time.process_time()
            ft = ex_this.extract(img)
            t_this.append(time.thread_time() - t0)
            p_this.append(time.process_time() - c0)
            same += all(np.array_equal(getattr(fb, f), getattr(ft, f)) for f in fields)
    pb, pt = np.median(t_base) * 1e3, np.median(t_this) * 1e3
    print(f"{a.dataset}: {len(images)} images x {a.reps}: base p50 {pb:.2f} ms, this p50 {pt:.2f} ms "
          f"(thread CPU per image), ratio {pt / pb:.3f}; identical output on {same} of {len(t_base)} images")
    # process CPU: also what helper threads (OpenBLAS, OpenCV's pool) spend for the calls
    qb, qt = np.median(p_base) * 1e3, np.median(p_this) * 1e3
    print(f"{'':{len(a.dataset) + 1}s} process CPU per image: base p50 {qb:.2f} ms, this p50 {qt:.2f} ms, ratio {qt / qb:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
