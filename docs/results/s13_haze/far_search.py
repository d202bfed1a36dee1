#!/usr/bin/env python
"""s13-haze: where tracked far points are lost on hazy frames: of the local-map points projected
into the image in the stage-2 search (TrackLocalMap), how many are matched and how many end as pose
inliers, by their depth in the camera (< 10, 10-20, 20-30, > 30 m), summed over the sequence.
Instruments the tracker's own search / refinement calls (read-only wrappers).

    CANOPY_CACHE_DIR=/work/cache PYTHONPATH=$PWD python docs/results/s13_haze/far_search.py <cell dir|clean> [tracking.x=v ...]
"""
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))
from benchmarks.bench_enhance_diagnose import actor_fast, enhance_pair  # noqa: E402
from canopy.backend import LocalMapper  # noqa: E402
from canopy.config import load_run_config, parse_value  # noqa: E402
from canopy.enhance import make_enhancer  # noqa: E402
from canopy.frontend import Tracker  # noqa: E402
from canopy.frontend.geometry import transform  # noqa: E402
from canopy.pipeline import MapUpdateSchedule, effective_map_update_lag  # noqa: E402
from canopy.sources import BUNDLED_DATA, open_source  # noqa: E402
from shared.types import StereoFrame  # noqa: E402

E = [10, 20, 30]
acc = {"view": np.zeros(4), "match": np.zeros(4), "inl": np.zeros(4), "ham_view": [[], [], [], []]}
last = {}


class Probe(Tracker):
    def _search(self, T_cw, pos, words, feats, kp_words, radius, scaled=False):
        q, r, in_view = super()._search(T_cw, pos, words, feats, kp_words, radius, scaled)
        if scaled:  # stage 2
            z = transform(T_cw, pos)[:, 2]
            b = np.digitize(z, E)
            for k in range(4):
                acc["view"][k] += ((b == k) & in_view).sum()
                acc["match"][k] += (b[q] == k).sum()
            last["q2z"] = z[q]
        return q, r, in_view

    def _refine(self, T_cw, X, r, feats, stereo, inliers=None, line_obs=None):
        est = super()._refine(T_cw, X, r, feats, stereo, inliers=inliers, line_obs=line_obs)
        last["est"] = (X, est)
        return est


cfg = load_run_config("kitti")
sets = {k.split(".", 1)[1]: parse_value(v) for k, v in (a.split("=", 1) for a in sys.argv[2:])}
tp = replace(cfg.tracking, **sets)
path = BUNDLED_DATA["kitti"] if sys.argv[1] == "clean" else sys.argv[1]
src = open_source("kitti", path)
enh = make_enhancer(cfg.enhancement)
tr = Probe(src.calibration, tp)
mapper = LocalMapper(src.calibration, cfg.mapping)
sched = MapUpdateSchedule(effective_map_update_lag(cfg.runtime.map_update_lag_frames, tp, cfg.runtime.sensor))
for i in range(len(src)):
    fr = src.frame(i)
    for u in sched.take_due(fr.index):
        tr.apply_map_update(u)
    le, re, info = enhance_pair(enh, fr.left, fr.right)
    last.clear()
    res = tr.track(StereoFrame(fr.index, fr.timestamp, le, re), **actor_fast(cfg.enhancement, info, le, tp.n_features))
    if res.is_keyframe and res.keyframe is not None:
        sched.keyframe_sent(res.keyframe.index, fr.index)
        sched.hold(mapper.insert_keyframe(res.keyframe))
    if "est" in last and res.status == "ok":
        X, est = last["est"]
        z = transform(est.T_cam_world, X)[:, 2]
        b = np.digitize(z[est.inliers], E)
        for k in range(4):
            acc["inl"][k] += (b == k).sum()
v, m, n = acc["view"], acc["match"], acc["inl"]
print(Path(path).name, "depth bins <10/10-20/20-30/>30 m: in view", v.astype(int).tolist(), "matched", m.astype(int).tolist(),
      "match rate", np.round(m / np.maximum(v, 1), 3).tolist(), "pose inliers", n.astype(int).tolist(),
      "inlier/match", np.round(n / np.maximum(m, 1), 3).tolist())
