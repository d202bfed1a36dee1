"""s16-darkhaze §1b: does the per-match Cramér-Rao disparity bound predict the stereo disparity error
against the clean pair's SGBM? Every 5th frame of the in-process run of a KITTI cell (or 'clean'). Usage:
    CANOPY_CACHE_DIR=/work/cache PYTHONPATH=$PWD python docs/results/s16_darkhaze/disp_sigma.py CELL_DIR|clean"""
import sys
from dataclasses import replace
from pathlib import Path
import numpy as np
sys.path.insert(0, '.')
from benchmarks.bench_enhance_diagnose import actor_fast, enhance_pair
from canopy.backend import LocalMapper
from canopy.config import load_run_config, parse_value
from canopy.degrade import disparity_sgbm
from canopy.enhance import make_enhancer
from canopy.enhance.noise import estimate_noise
from canopy.frontend import Tracker
from canopy.frontend.keypoint_uncertainty import row_gradient_energy
from canopy.pipeline import MapUpdateSchedule, effective_map_update_lag
from canopy.sources import BUNDLED_DATA, open_source
from shared.types import StereoFrame
path = sys.argv[1]
cfg = load_run_config("kitti")
enh = replace(cfg.enhancement, method="auto"); tp = cfg.tracking
path = BUNDLED_DATA["kitti"] if path == "clean" else path
src, clean = open_source("kitti", path), open_source("kitti", BUNDLED_DATA["kitti"])
enhancer = make_enhancer(enh); tracker = Tracker(src.calibration, tp)
mapper = LocalMapper(src.calibration, cfg.mapping)
schedule = MapUpdateSchedule(effective_map_update_lag(cfg.runtime.map_update_lag_frames, tp, cfg.runtime.sensor))
bf = src.calibration.bf
sf = tp.scale_factor ** np.arange(tp.n_levels)
E, SD, Z, DD = [], [], [], []
for i in range(len(src)):
    fr = src.frame(i)
    for u in schedule.take_due(fr.index):
        tracker.apply_map_update(u)
    le, re, info = enhance_pair(enhancer, fr.left, fr.right)
    res = tracker.track(StereoFrame(fr.index, fr.timestamp, le, re), **actor_fast(enh, info, le, tp.n_features))
    if res.is_keyframe and res.keyframe is not None:
        schedule.keyframe_sent(res.keyframe.index, fr.index)
        schedule.hold(mapper.insert_keyframe(res.keyframe))
    if i % 5 or tracker._stereo_last is None:
        continue
    feats, st = tracker._contour_inputs[2], tracker._stereo_raw
    ok = st.valid
    uv = feats.uv[ok]; oc = feats.octave[ok]
    d_est = uv[:, 0] - st.u_right[ok]
    sn = estimate_noise(le, rows_fraction=0.5)
    sxx, n = row_gradient_energy(le, uv, sf[oc], tp.subpixel_window)
    sig = np.maximum(sxx - n * sn**2 / 2, 1e-9)
    sd = np.sqrt(2 * sn**2 / sig) * sf[oc]
    c = clean.frame(i)
    ref = disparity_sgbm(c.left, c.right).astype(float)
    h, w = ref.shape
    d_ref = ref[np.clip(np.rint(uv[:, 1]).astype(int), 0, h - 1), np.clip(np.rint(uv[:, 0]).astype(int), 0, w - 1)]
    m = d_ref > 0
    E.append((d_est - d_ref)[m]); SD.append(sd[m]); DD.append(d_est[m]); Z.append(bf / d_ref[m])
E, SD, Z, DD = map(np.concatenate, (E, SD, Z, DD))
print(Path(path).name, "n", len(E))
rel = SD / DD
for name, v in (("sigma_d px", SD), ("sigma_d/d", rel)):
    qs = np.percentile(v, [0, 20, 40, 60, 80, 90, 95, 100])
    print(" by", name)
    for lo, hi in zip(qs[:-1], qs[1:]):
        mm = (v >= lo) & (v <= hi)
        e = E[mm]
        print("   %.3f-%.3f n %5d |dd| p50 %.2f rms(clip 5) %.2f >1px %3.0f%%  rel depth err p50 %.3f  z p50 %.1f" % (
            lo, hi, mm.sum(), np.median(np.abs(e)), np.sqrt(np.mean(np.clip(e, -5, 5)**2)), 100*np.mean(np.abs(e) > 1),
            np.median(np.abs(e) / DD[mm]), np.median(Z[mm])))
