#!/usr/bin/env python
"""s14-darkhaze: the tracker's own stereo points on a degraded KITTI cell (every 5th frame of the
in-process run, as diag_frames.py runs it) against the clean pair's SGBM disparity at their pixel
(KITTI has no depth truth; s13-haze's reference): points per frame, |disparity error| p50 / share
> 1 px, by clean depth band. Run:

    CANOPY_CACHE_DIR=/work/cache PYTHONPATH=$PWD python docs/results/s14_darkhaze/stereo_depth.py <cell dir|clean> [--set ...]
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))

from benchmarks.bench_enhance_diagnose import actor_fast, enhance_pair  # noqa: E402
from canopy.backend import LocalMapper  # noqa: E402
from canopy.config import load_run_config, parse_value  # noqa: E402
from canopy.degrade import disparity_sgbm  # noqa: E402
from canopy.enhance import make_enhancer  # noqa: E402
from canopy.frontend import Tracker  # noqa: E402
from canopy.pipeline import MapUpdateSchedule, effective_map_update_lag  # noqa: E402
from canopy.sources import BUNDLED_DATA, open_source  # noqa: E402
from shared.types import StereoFrame  # noqa: E402

BANDS = ((0, 10), (10, 20), (20, 1e9))


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("path")
    ap.add_argument("--set", action="append", default=[])
    ap.add_argument("--step", type=int, default=5)
    a = ap.parse_args()
    sets = {"tracking": {}, "mapping": {}, "enhancement": {}}
    for s in a.set:
        k, v = s.split("=", 1)
        sec, f = k.split(".", 1)
        sets[sec][f] = parse_value(v)
    cfg = load_run_config("kitti")
    enh = replace(cfg.enhancement, method="auto", **sets["enhancement"])
    tp = replace(cfg.tracking, **sets["tracking"])
    path = BUNDLED_DATA["kitti"] if a.path == "clean" else a.path
    src, clean = open_source("kitti", path), open_source("kitti", BUNDLED_DATA["kitti"])
    enhancer = make_enhancer(enh)
    tracker = Tracker(src.calibration, tp)
    mapper = LocalMapper(src.calibration, replace(cfg.mapping, **sets["mapping"]))
    schedule = MapUpdateSchedule(effective_map_update_lag(cfg.runtime.map_update_lag_frames, tp, cfg.runtime.sensor))
    bf = src.calibration.bf
    n_pts, errs = [], {b: [] for b in BANDS}
    for i in range(len(src)):
        fr = src.frame(i)
        for u in schedule.take_due(fr.index):
            tracker.apply_map_update(u)
        le, re, info = enhance_pair(enhancer, fr.left, fr.right)
        res = tracker.track(StereoFrame(fr.index, fr.timestamp, le, re), **actor_fast(enh, info, le, tp.n_features))
        if res.is_keyframe and res.keyframe is not None:
            schedule.keyframe_sent(res.keyframe.index, fr.index)
            schedule.hold(mapper.insert_keyframe(res.keyframe))
        if i % a.step or tracker._stereo_last is None:
            continue
        feats, st = tracker._contour_inputs[2], tracker._stereo_last
        ok = st.valid
        uv = feats.uv[ok]
        d_est = uv[:, 0] - st.u_right[ok]
        c = clean.frame(i)
        ref = disparity_sgbm(c.left, c.right).astype(float)
        h, w = ref.shape
        d_ref = ref[np.clip(np.rint(uv[:, 1]).astype(int), 0, h - 1), np.clip(np.rint(uv[:, 0]).astype(int), 0, w - 1)]
        n_pts.append(int(ok.sum()))
        scored = d_ref > 0
        z_ref = np.where(scored, bf / np.maximum(d_ref, 1e-6), np.inf)
        for lo, hi in BANDS:
            m = scored & (z_ref >= lo) & (z_ref < hi)
            errs[(lo, hi)].append(d_est[m] - d_ref[m])
    out = [f"{Path(path).name} {a.set}: stereo points / frame p50 {np.median(n_pts):.0f}"]
    for b in BANDS:
        e = np.concatenate(errs[b]) if errs[b] else np.zeros(0)
        if len(e):
            out.append(f"{b[0]}-{b[1] if b[1] < 1e8 else 'inf'} m: n {len(e)}, |dd| p50 {np.median(np.abs(e)):.2f} px, "
                       f"> 1 px {100 * np.mean(np.abs(e) > 1):.0f} %, bias {np.median(e):+.2f} px")
    print("; ".join(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
