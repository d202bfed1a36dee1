"""s17-kittihaze: per-frame and per-stereo-point evidence on a KITTI cell, in process as the grid runs it.

Per frame: the enhancer's decision, its pre-filter sigma, gamma, eps factor, the tracker's robust sigma.
Per stereo point (the tracker's own matches, _stereo_raw): pixel, octave, depth, the disparity error
against the clean pair's SGBM, the SAD window's row-gradient energy on the enhanced left image, and the
same energy of the *noise field* after enhancement, measured from a second noise draw of the same cell
(enhanced(draw A) - enhanced(draw B)) / sqrt 2: the noise the SAD actually sees (diagnosis only).
Usage: diag_stereo.py CELL_DIR OTHER_DRAW_DIR OUT.npz [--set sec.key=val ...]"""
import json
import sys
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))
from benchmarks.bench_enhance_diagnose import actor_fast, enhance_pair  # noqa: E402
from canopy.backend import LocalMapper  # noqa: E402
from canopy.config import load_run_config, parse_value  # noqa: E402
from canopy.degrade import disparity_sgbm  # noqa: E402
from canopy.enhance import make_enhancer  # noqa: E402
from canopy.enhance.noise import estimate_noise  # noqa: E402
from canopy.frontend import Tracker  # noqa: E402
from canopy.frontend.keypoint_uncertainty import row_gradient_energy  # noqa: E402
from canopy.pipeline import MapUpdateSchedule, effective_map_update_lag  # noqa: E402
from canopy.sources import BUNDLED_DATA, open_source  # noqa: E402
from shared.types import StereoFrame  # noqa: E402

path, other, out = sys.argv[1:4]
sets = {"tracking": {}, "mapping": {}, "enhancement": {}}
for s in sys.argv[4:]:
    if s == "--set":
        continue
    k, v = s.split("=", 1)
    sec, f = k.split(".", 1)
    sets[sec][f] = parse_value(v)
cfg = load_run_config("kitti")
enh = replace(cfg.enhancement, method="auto", **sets["enhancement"])
tp = replace(cfg.tracking, **sets["tracking"])
src, src_b, clean = open_source("kitti", path), open_source("kitti", other), open_source("kitti", BUNDLED_DATA["kitti"])
enhancer, enhancer_b = make_enhancer(enh), make_enhancer(enh)
tracker = Tracker(src.calibration, tp)
mapper = LocalMapper(src.calibration, replace(cfg.mapping, **sets["mapping"]))
schedule = MapUpdateSchedule(effective_map_update_lag(cfg.runtime.map_update_lag_frames, tp, cfg.runtime.sensor))
sf = tp.scale_factor ** np.arange(tp.n_levels)
frames, pts = [], []
for i in range(len(src)):
    fr = src.frame(i)
    for u in schedule.take_due(fr.index):
        tracker.apply_map_update(u)
    le, re, info = enhance_pair(enhancer, fr.left, fr.right)
    res = tracker.track(StereoFrame(fr.index, fr.timestamp, le, re), **actor_fast(enh, info, le, tp.n_features))
    if res.is_keyframe and res.keyframe is not None:
        schedule.keyframe_sent(res.keyframe.index, fr.index)
        schedule.hold(mapper.insert_keyframe(res.keyframe))
    feats, st = tracker._contour_inputs[2], tracker._stereo_raw
    frames.append(dict(i=i, method=info["method"], noise_sigma=float(info["noise_sigma"]), gamma=float(info["gamma"]),
                       eps_factor=float(info["eps_factor"]), robust=feats.robust_noise_sigma,
                       est_enh=estimate_noise(le, rows_fraction=0.5), est_raw=estimate_noise(fr.left, rows_fraction=0.5),
                       status=res.status, inl=int(res.n_inliers)))
    if st is None:
        continue
    ok = np.flatnonzero(st.valid)
    uv = feats.uv[ok].astype(np.float32); oc = feats.octave[ok]
    d_est = uv[:, 0] - st.u_right[ok]
    sxx, n = row_gradient_energy(le, uv, sf[oc], tp.subpixel_window)
    frb = src_b.frame(i)
    le_b, _, _ = enhance_pair(enhancer_b, frb.left, frb.right)
    noise_field = (le.astype(np.float32) - le_b.astype(np.float32)) / np.sqrt(2.0)
    nxx, _ = row_gradient_energy(noise_field, uv, sf[oc], tp.subpixel_window)
    c = clean.frame(i)
    ref = disparity_sgbm(c.left, c.right).astype(float)
    h, w = ref.shape
    d_ref = ref[np.clip(np.rint(uv[:, 1]).astype(int), 0, h - 1), np.clip(np.rint(uv[:, 0]).astype(int), 0, w - 1)]
    nv = cv2.blur(noise_field ** 2, (11, 11))  # the noise's variance over an 11x11 level-0 window
    nvar = nv[np.clip(np.rint(uv[:, 1]).astype(int), 0, h - 1), np.clip(np.rint(uv[:, 0]).astype(int), 0, w - 1)]
    uncertain = tracker._uncertain_mask(tracker._stereo_last)
    pts.append(np.column_stack([np.full(len(ok), i), uv, oc, st.depth[ok], d_est, d_ref, sxx, nxx, nvar,
                                np.zeros(len(ok)) if uncertain is None else uncertain[ok]]))
np.savez(out, frames=json.dumps(frames), pts=np.concatenate(pts), n=n,
         cols="i u v oct depth d_est d_ref sxx nxx nvar uncertain")
print("done", out, len(frames))
