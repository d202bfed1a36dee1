"""Per-frame jitter diagnosis of one EuRoC grid cell as the grid runs it (in process, auto enhancement).

Throw-away measurement script (docs/notes/s13-euroc.md), run from the worktree root:
    CELL=g1-b0.06-low python docs/results/s13_euroc/jitter.py [tracking.name=value ...] [enhancement.name=value ...]
CELL=clean runs the bundled snippet. Wraps refine_pose / Tracker.track (no code change) and prints: ATE, keyframes,
per-frame inliers / stereo inliers / octave mix / depth, frame-diff of the aligned error, the error split into
the part shared by a keyframe segment (map) and the within-segment part (per-frame pose noise), and the
linear decomposition of the frame-to-frame pose change into keypoint (u,v), disparity and churn parts.
"""
import os, sys, warnings
warnings.simplefilter("ignore")
sys.path.insert(0, os.getcwd())
import numpy as np
import canopy.frontend.map_tracking as mt
import canopy.frontend.tracker as trk
from benchmarks.bench_enhance_diagnose import run
from canopy.config import parse_value
from canopy.sources import BUNDLED_DATA
from canopy.metrics import align_trajectory
from canopy.frontend.geometry import project_stereo, stereo_pose_jacobian

calls, frames = [], []
orig = mt.refine_pose


def rp(T, X, meas, hr, sigma, calib, *a, **k):
    est = orig(T, X, meas, hr, sigma, calib, *a, **k)
    calls.append(dict(X=np.asarray(X).copy(), meas=np.asarray(meas, float).copy(), hr=np.asarray(hr, bool).copy(),
                      sigma=np.asarray(sigma).copy(), inl=est.inliers.copy(), T=est.T_cam_world.copy(),
                      info=est.information.copy()))
    return est


mt.refine_pose = rp
origtrack = trk.Tracker.track


def track(self, frame, *a, **k):
    calls.clear()
    res = origtrack(self, frame, *a, **k)
    frames.append(dict(T=res.T_world_cam.copy(), c=dict(calls[-1]) if calls else None, kf=res.is_keyframe,
                       ncalls=len(calls)))
    return res


trk.Tracker.track = track
kfargs = []
_kr = trk.keyframe_reasons


def kr(p, since, ratio, n_ref, ref_first, n_tc, n_nc, *rest):  # *rest: later keyframe_reasons arguments (s14)
    out = _kr(p, since, ratio, n_ref, ref_first, n_tc, n_nc, *rest)
    kfargs.append((since, ratio if ratio is not None else float('nan'), n_ref, ref_first or 0, n_tc, n_nc, '+'.join(out)))
    return out


trk.keyframe_reasons = kr
cell = os.environ.get("CELL", "g1-b0.06-low")
seed = os.environ.get("SEED", "0")
path = BUNDLED_DATA["euroc"] if cell == "clean" else f"/work/cache/degraded/euroc-all-{cell}-seed{seed}"
enh, tr, mp = {"method": "auto"}, {}, {}
for s in sys.argv[1:]:
    key, v = s.split("=", 1)
    sec, name = key.split(".")
    (enh if sec == "enhancement" else mp if sec == "mapping" else tr)[name] = parse_value(v)
# the mapper's poses: capture through the returned rows is not enough, so re-run's est comes from run()
import benchmarks.bench_enhance_diagnose as bed
cap = {}
orig_ape = bed.ape


def ape_cap(est, gt, align):
    cap["est"], cap["gt"] = est.copy(), gt.copy()
    return orig_ape(est, gt, align)


bed.ape = ape_cap
out, rows = run(path, BUNDLED_DATA["euroc"], "euroc", enh, tr, None, stereo=False, kind="euroc", map_sets=mp)
est, gt = cap["est"], cap["gt"]
online = np.array([f["T"] for f in frames])
kfs = [i for i, f in enumerate(frames) if f["kf"]]
methods = {}
for r in rows:
    methods[r["method"]] = methods.get(r["method"], 0) + 1
al = align_trajectory(est, gt, with_scale=False)
e = al[:, :3, 3] - gt[:, :3, 3]
alo = align_trajectory(online, gt, with_scale=False)
eo = alo[:, :3, 3] - gt[:, :3, 3]
ate = np.sqrt((e ** 2).sum(1).mean()) * 1e3
print(f"CELL {cell} seed {seed} {sys.argv[1:]} methods {methods}")
print(f"ATE final {ate:.4f} mm (grid {out.get('ate', float('nan')) * 1e3:.4f}) online {np.sqrt((eo ** 2).sum(1).mean()) * 1e3:.4f} mm; keyframes {len(kfs)} {kfs}")
seg = np.zeros(len(e), int)
b = kfs + [len(e)]
for k, (a0, a1) in enumerate(zip(b[:-1], b[1:])):
    seg[a0:a1] = k
segmean = np.array([e[seg == s].mean(0) for s in seg])
print("err rms: between-segment %.3f, within-segment %.3f; frame-diff %.3f mm; per axis (world) %s" % (
    np.sqrt((segmean ** 2).sum(1).mean()) * 1e3, np.sqrt(((e - segmean) ** 2).sum(1).mean()) * 1e3,
    np.sqrt((np.diff(e, axis=0) ** 2).sum(1).mean()) * 1e3, np.round(np.sqrt((e ** 2).mean(0)) * 1e3, 3)))
ec = np.einsum('nji,nj->ni', gt[:, :3, :3], e)
print("err rms per camera axis x,y,z mm:", np.round(np.sqrt((ec ** 2).mean(0)) * 1e3, 3))
N, NI, NS, OCT, Z, SD = [], [], [], [], [], []
for f in frames:
    c = f["c"]
    if c is None:
        continue
    m = c["inl"]
    Pc = c["X"] @ c["T"][:3, :3].T + c["T"][:3, 3]
    N.append(len(m)); NI.append(m.sum()); NS.append((m & c["hr"]).sum())
    OCT.append(np.round(np.log(c["sigma"][m] / c["sigma"].min()) / np.log(1.2)).astype(int) if m.any() else [])
    Z.append(Pc[m, 2])
    cov = np.linalg.inv(c["info"]); R = c["T"][:3, :3]
    # camera-centre covariance: c = -R^T t, dxi = (w, v) left-perturbation -> dc = -R^T dv + ... (approx translation part)
    SD.append(np.sqrt(np.trace(cov[3:, 3:])) if cov.shape == (6, 6) else np.nan)
octs = np.concatenate([np.asarray(o) for o in OCT])
Zc = np.concatenate(Z)
print("per frame: matches med %d, inliers med %d (min %d), stereo inliers med %d; predicted t-sd med %.3f mm" % (
    np.median(N), np.median(NI), np.min(NI), np.median(NS), np.nanmedian(SD) * 1e3))
print("inlier octave histogram (share):", np.round(np.bincount(octs, minlength=8) / len(octs), 3))
print("inlier depth quantiles 5/50/95:", np.round(np.quantile(Zc, [.05, .5, .95]), 2))
# frame-to-frame: keypoint change of common inliers and churn
dv, churn, lv = [], [], []
prev = None
for f in frames:
    c = f["c"]
    if c is None:
        prev = None; continue
    m = c["inl"]
    keys = {tuple(np.round(c["X"][j], 9)): j for j in np.flatnonzero(m)}
    if prev is not None:
        pc, pk = prev
        com = [k for k in keys if k in pk]
        churn.append(1 - len(com) / max(len(keys), 1))
        for k in com:
            dv.append(c["meas"][keys[k], :2] - pc["meas"][pk[k], :2]); lv.append(c["sigma"][keys[k]] != pc["sigma"][pk[k]])
    prev = (c, keys)
dv = np.array(dv)
print("common inliers: change rms %.3f px, identical %.3f, level changed %.3f; churn %.3f" % (
    np.sqrt((dv ** 2).sum(1).mean()), (np.abs(dv).max(1) == 0).mean(), np.mean(lv), np.mean(churn)))
ka = np.array([a[:6] for a in kfargs], float)
print("keyframe inputs med: ratio %.3f n_ref %d tracked_close %d new_close %d; reasons fired %s" % (
    np.nanmedian(ka[:, 1]), np.median(ka[:, 2]), np.median(ka[:, 4]), np.median(ka[:, 5]), sorted(set(a[6] for a in kfargs if a[6]))))
print("SUMMARY %s %s ATE %.4f frame-diff %.3f kfs %d inl %d" % (cell, sys.argv[1:], ate, np.sqrt((np.diff(e, axis=0) ** 2).sum(1).mean()) * 1e3, len(kfs), np.median(NI)))
if os.environ.get("SAVE"):
    np.savez(os.environ["SAVE"], e=e, eo=eo, kfs=np.array(kfs), ni=np.array(NI), ns=np.array(NS))
