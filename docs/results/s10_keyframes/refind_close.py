"""s10-keyframes diagnostic: for each frame right after a keyframe, how many of that keyframe's new close
landmarks project into the image, are matched, and (unmatched) have a keypoint near their projection
(KITTI 06 snippet, kitti config, in process). Run from the repo root: PYTHONPATH=$PWD python <this file>."""
import sys, numpy as np
sys.path.insert(0, '.')
from canopy.config import load_run_config
from canopy.sources import open_source
from canopy.frontend import Tracker
from canopy.backend import LocalMapper
from canopy.pipeline import MapUpdateSchedule, effective_map_update_lag
from canopy.frontend.geometry import project_stereo, se3_inv
src = open_source("kitti", None)
frames = [src.frame(i) for i in range(len(src))]
cfg = load_run_config("kitti"); tp, mp, rt = cfg.tracking, cfg.mapping, cfg.runtime
calib = src.calibration
tr, mapper = Tracker(calib, tp), LocalMapper(calib, mp)
sch = MapUpdateSchedule(effective_map_update_lag(rt.map_update_lag_frames, tp))
prev_kf = None
H = []
import canopy.frontend.tracker as T
cap = {}
_otf = T.Tracker._track_frame
def _tf(self, frame, feats, stereo, timings, lines=None):
    cap['feats'] = feats
    return _otf(self, frame, feats, stereo, timings, lines)
T.Tracker._track_frame = _tf
def pc(a): return np.unpackbits(a, axis=-1).sum(-1)
for f in frames:
    for u in sch.take_due(f.index): tr.apply_map_update(u)
    res = tr.track(f)
    if prev_kf is not None and prev_kf.index in tr._provisional:
        kf = prev_kf
        ids, pos, desc = tr._provisional[kf.index]
        # close ones in the KF
        sel = kf.new_landmark_ids >= 0
        dep = kf.depth[sel]
        close = dep < tp.close_depth_baselines * calib.baseline
        ids, pos, desc = ids[close], pos[close], desc[close]
        T_cw = se3_inv(res.T_world_cam)
        proj, Pc = project_stereo(T_cw, pos, calib)
        inimg = (Pc[:,2]>0)&(proj[:,0]>=0)&(proj[:,0]<calib.width)&(proj[:,1]>=0)&(proj[:,1]<calib.height)
        matched = np.isin(ids, tr._last_matched[2])
        view_has = np.isin(ids, tr._map_view().ids)
        F = cap['feats']
        um = inimg & ~matched
        d = np.linalg.norm(proj[um, None, :2] - F.uv[None].astype(float), axis=2)  # (m, K)
        near = d < 4.0 * 1.2 ** 2
        hd = pc(np.bitwise_xor(desc[um][:, None, :], F.descriptors[None]))
        hd_near = np.where(near, hd, 999).min(1)
        anyk = near.any(1)
        hd_all = pc(np.bitwise_xor(desc[inimg][:, None, :], F.descriptors[None]))
        d_all = np.linalg.norm(proj[inimg, None, :2] - F.uv[None].astype(float), axis=2)
        cand = np.where(hd_all <= 60, d_all, 1e9).min(1)
        H.append(cand)
        print("   unmatched-in-image", int(um.sum()), "with kp within 5.8px", int(anyk.sum()), "best hamming<=100 there", int((hd_near<=100).sum()), "<=75", int((hd_near<=75).sum()), "<=50", int((hd_near<=50).sum()))
        print(f.index, "kf", kf.index, "close new lms", len(ids), "in image", int(inimg.sum()), "in view", int(view_has.sum()), "matched now", int(matched.sum()), "status", res.status, res.keyframe_reason)
    if res.is_keyframe and res.keyframe is not None:
        u = mapper.insert_keyframe(res.keyframe); sch.keyframe_sent(res.keyframe.index, f.index); sch.hold(u)
        prev_kf = res.keyframe
    else:
        prev_kf = None

h = np.concatenate(H); h = h[h < 1e8]
print("in-image close KF landmarks with a keypoint of hamming<=60 anywhere:", len(h), "distance px percentiles 25/50/75/90:", np.percentile(h, [25, 50, 75, 90]).round(1), "frac<=4", (h<=4).mean().round(2), "frac<=6", (h<=6).mean().round(2), "frac<=10", (h<=10).mean().round(2))
