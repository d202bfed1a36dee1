"""s29-scale: the tracker's stereo disparities on a generated preset's frames (enhanced as the actors enhance them)
against the renderer's exact depth (the presets' rectification is the identity), binned by image row: a depth
error that changes with the row bends the map and makes the path sink.

    python docs/results/s29_scale/row_bias.py CELL_OR_CLEAN_FOLDER PRESET [--every 10] [--frames 300]
"""
import argparse
import os
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))
import benchmarks.bench_enhance_diagnose as bed  # noqa: E402
from canopy.config import load_run_config  # noqa: E402
from canopy.enhance import make_enhancer  # noqa: E402
from canopy.frontend import Tracker  # noqa: E402
from canopy.frontend.stereo import match_stereo  # noqa: E402
from canopy.sources import open_source  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("path")
ap.add_argument("preset")
ap.add_argument("--every", type=int, default=10)
ap.add_argument("--frames", type=int, default=300)
a = ap.parse_args()
cache = os.environ.get("CANOPY_CACHE_DIR", "/work/cache")
clean = open_source("euroc", f"{cache}/synthetic/{a.preset}-seed0-full", max_frames=a.frames)
src = open_source("euroc", a.path, max_frames=a.frames)
cfg = load_run_config("synthetic")
enhancer = make_enhancer(cfg.enhancement)
tracker = Tracker(src.calibration, cfg.tracking)
c = src.calibration
depth_dir = Path(clean.left_paths[0]).parents[2] / "depth0" / "data"
bands = np.linspace(0, c.height, 7)
rows = []
for i in range(0, len(src), a.every):
    fr = src.frame(i)
    le, re, info = bed.enhance_pair(enhancer, fr.left, fr.right)
    kw = bed.actor_fast(cfg.enhancement, info, le, cfg.tracking.n_features, "actor")
    thr = kw.get("fast_threshold")
    fl = tracker.extractor.extract(le, thr, kw.get("fast_fallback"), kw.get("fast_min_keypoints", 0))
    frr = tracker.extractor_right.extract(re, thr, kw.get("fast_fallback"), kw.get("fast_min_keypoints", 0))
    st = match_stereo(fl, frr, le, re, c, tracker.params)
    ok = st.valid
    uv = fl.uv[ok]
    d = uv[:, 0] - st.u_right[ok]
    z = cv2.imread(str(depth_dir / Path(clean.left_paths[i]).name), cv2.IMREAD_UNCHANGED).astype(float) / 1000.0
    zt = z[np.clip(np.rint(uv[:, 1]).astype(int), 0, c.height - 1), np.clip(np.rint(uv[:, 0]).astype(int), 0, c.width - 1)]
    good = zt > 0
    dt = c.bf / np.where(good, zt, 1.0)
    rows.append(np.column_stack([uv[good, 1], d[good] - dt[good], dt[good]]))
r = np.concatenate(rows)
print(f"{a.path}: {len(r)} stereo points on {len(rows)} frames")
print("rows        n     mean err px (|err|<=1)  >1 px   mean depth err % (|err|<=1)")
for lo, hi in zip(bands[:-1], bands[1:]):
    m = (r[:, 0] >= lo) & (r[:, 0] < hi)
    e, dt = r[m, 1], r[m, 2]
    near = np.abs(e) <= 1.0
    if m.sum() == 0:
        continue
    print(f"{int(lo):3d}-{int(hi):3d}  {m.sum():6d}  {np.mean(e[near]):+.3f}              {np.mean(~near):5.1%}  "
          f"{100 * np.mean(-e[near] / (dt[near] + e[near])):+.2f}")
