#!/usr/bin/env python
"""cProfile (thread CPU clock) of the base checkout's and this checkout's CellExtractor on the same
KITTI left images, image by image alternating (s15-extract): per-function ms per image, side by side.
cProfile inflates calls by its own overhead: read the split, not the totals.

    git archive bcd2717 | tar -x -C /tmp/s15x/base
    PYTHONPATH=$PWD python docs/results/s15_extract/ab_profile.py --base /tmp/s15x/base --n 20 --reps 2
"""
from __future__ import annotations

import argparse
import cProfile
import pstats
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT))

from ab_checkout import load_module  # noqa: E402
from canopy.config import load_run_config  # noqa: E402
from canopy.sources import open_source  # noqa: E402

BUILTINS = {  # substring of a C function's name in the stats -> row label (own time)
    "'detect' of": "FAST detect (cv2)", "'compute' of": "ORB.compute (cv2)", "<resize>": "pyramid resize (cv2)",
    "c_einsum": "einsum (angles)", "numpy.fromiter": "np.fromiter (FAST scores)", "KeyPoint_convert": "KeyPoint_convert",
    "'argsort' of": "argsort", "'at' of": "np.minimum.at",
}
NAMES = {  # Python function name in the stats -> row label (cumulative)
    "quadtree_select": "quadtree_select (cum.)", "ic_angles": "ic_angles (cum.)", "ic_angles_levels": "ic_angles_levels (cum.)",
    "_fallback_corners": "_fallback_corners (cum.)", "detect_level": "detect_level (cum.)",
    "image_noise_sigma": "image_noise_sigma (cum.)", "keypoints": "KeyPointPool.keypoints (cum.)",
}


def per_function(prof: cProfile.Profile, n: int) -> dict[str, float]:
    st = pstats.Stats(prof).stats
    out: dict[str, float] = {}
    for (fname, _, fn), (_, _, tt, ct, _) in st.items():
        if fname == "~":
            for sub, label in BUILTINS.items():
                if sub in fn:
                    out[label] = out.get(label, 0.0) + tt * 1e3 / n
            continue
        if fn in NAMES:
            cum = NAMES[fn].endswith("(cum.)")
            out[NAMES[fn]] = out.get(NAMES[fn], 0.0) + (ct if cum else tt) * 1e3 / n
        if fn == "extract" and ct > 0:
            out["extract total"] = out.get("extract total", 0.0) + ct * 1e3 / n
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--base", type=Path, required=True)
    ap.add_argument("--n", type=int, default=20)
    ap.add_argument("--reps", type=int, default=2)
    a = ap.parse_args()
    rel = Path("canopy/frontend/cell_extractor.py")
    base = load_module(a.base / rel, "base_cell_extractor")
    this = load_module(ROOT / rel, "this_cell_extractor")
    tp = load_run_config("kitti").tracking
    exs = {"base": base.CellExtractor(tp, responses=False), "this": this.CellExtractor(tp, responses=False)}
    src = open_source("kitti", max_frames=a.n)
    imgs = [src.frame(i).left for i in range(len(src))]
    for ex in exs.values():
        ex.extract(imgs[0])
    profs = {k: cProfile.Profile(time.thread_time) for k in exs}
    for _ in range(a.reps):
        for img in imgs:
            for k, ex in exs.items():
                profs[k].enable()
                ex.extract(img)
                profs[k].disable()
    n = a.reps * len(imgs)
    rows = {k: per_function(p, n) for k, p in profs.items()}
    labels = sorted(set(rows["base"]) | set(rows["this"]), key=lambda r: -max(rows["base"].get(r, 0), rows["this"].get(r, 0)))
    print(f"{'ms per image (cProfile, thread CPU)':40s} {'base':>8s} {'this':>8s}")
    for r in labels:
        print(f"{r:40s} {rows['base'].get(r, 0):8.2f} {rows['this'].get(r, 0):8.2f}")


if __name__ == "__main__":
    main()
