"""s24-dimhaze scratch: what is left of a preset cell's ATE (scale vs shape, stereo depth vs exact depth,
oracle depths). Runs benchmarks/bench_enhance_diagnose.run (the grid's in-process loop) with hooks."""
import argparse, json, sys
from pathlib import Path
import numpy as np, cv2
sys.path.insert(0, str(Path.cwd()))
import benchmarks.bench_enhance_diagnose as bd
import canopy.frontend.tracker_worker as tw
from canopy.frontend.stereo import StereoMatches
from canopy.frontend.geometry import se3_inv
from benchmarks.diagnose_drift import relative_rotation_errors
from canopy.config import parse_value

ap = argparse.ArgumentParser()
ap.add_argument("--path", required=True); ap.add_argument("--clean", required=True)
ap.add_argument("--max-frames", type=int, default=300)
ap.add_argument("--set", action="append", default=[])
ap.add_argument("--enh", action="append", default=[])
ap.add_argument("--oracle", choices=("none", "drop", "exact", "drop5", "exact5"), default="none")
ap.add_argument("--tol", type=float, default=0.10)
ap.add_argument("--out", default=None)
a = ap.parse_args()
files = sorted((Path(a.path) / "mav0" / "depth0" / "data").iterdir())
state = {"i": -1}
recs = []
orig_enh = bd.enhance_pair
def enh(*args, **kw):
    state["i"] += 1
    state["depth"] = cv2.imread(str(files[state["i"]]), cv2.IMREAD_UNCHANGED).astype(np.float32) / 1000.0
    out = orig_enh(*args, **kw)
    state["method"] = out[2]["method"]
    return out
bd.enhance_pair = enh
orig_ms = tw.match_stereo
def ms(left, right, li, ri, calib, params, *args, **kw):
    st = orig_ms(left, right, li, ri, calib, params, *args, **kw)
    z = state["depth"]; h, w = z.shape
    v = np.flatnonzero(st.valid)
    x = np.clip(np.round(left.uv[v, 0]).astype(int), 0, w - 1); y = np.clip(np.round(left.uv[v, 1]).astype(int), 0, h - 1)
    zt = z[y, x]
    rel = st.depth[v] / np.maximum(zt, 1e-6) - 1.0
    # the 5x5 neighbourhood's depth closest to the stereo depth (a silhouette corner's pixel may be background)
    best = np.full(len(v), np.inf)
    for dy in range(-2, 3):
        for dx in range(-2, 3):
            zz = z[np.clip(y + dy, 0, h - 1), np.clip(x + dx, 0, w - 1)]
            r5 = np.where(zz > 0, st.depth[v] / np.maximum(zz, 1e-6) - 1.0, np.inf)
            best = np.where(np.abs(r5) < np.abs(best), r5, best)
    # every left keypoint's foreground depth (5x5 min off sky): how many far ones FAST found, how many got stereo
    zz5 = z.copy(); zz5[zz5 <= 0] = np.inf
    fg = cv2.erode(zz5, np.ones((5, 5), np.uint8))
    xa = np.clip(np.round(left.uv[:, 0]).astype(int), 0, w - 1); ya = np.clip(np.round(left.uv[:, 1]).astype(int), 0, h - 1)
    zk = fg[ya, xa]
    far = np.isfinite(zk) & (zk > 10)
    state.setdefault("far", []).append((len(left), int(far.sum()), int((far & st.valid).sum()), int(np.isinf(zk).sum())))
    recs.append(dict(i=state["i"], n_kp=len(left), n=len(v), zt=zt, rel=rel, rel5=best, y=left.uv[v, 1], oct=left.octave[v]))
    if a.oracle == "none":
        return st
    u, d = st.u_right.copy(), st.depth.copy()
    if a.oracle in ("drop5", "exact5"):  # against the 5x5 neighbourhood's depth closest to the stereo one
        bad5 = ~np.isfinite(best) | (np.abs(best) > a.tol)
        if a.oracle == "drop5":
            u[v[bad5]] = -1.0; d[v[bad5]] = -1.0
        else:  # that exact depth for every match within 25 % of one, the rest dropped
            keep = np.isfinite(best) & (np.abs(best) <= 0.25)
            zz = st.depth[v] / (1.0 + np.where(keep, best, 0.0))
            d[v[keep]] = zz[keep]; u[v[keep]] = left.uv[v[keep], 0] - calib.bf / zz[keep]
            u[v[~keep]] = -1.0; d[v[~keep]] = -1.0
        return StereoMatches(u, d, n_candidates=st.n_candidates, on_contour=st.on_contour)
    bad = (zt <= 0) | (np.abs(rel) > a.tol)
    if a.oracle == "drop":
        u[v[bad]] = -1.0; d[v[bad]] = -1.0
    else:  # exact depth (and the matching right column) for every valid non-sky match
        good = zt > 0
        d[v[good]] = zt[good]
        u[v[good]] = left.uv[v[good], 0] - calib.bf / zt[good]
        u[v[~good]] = -1.0; d[v[~good]] = -1.0
    return StereoMatches(u, d, n_candidates=st.n_candidates, on_contour=st.on_contour)
tw.match_stereo = ms
cap = {}
orig_traj = bd.TrajectoryRecorder.trajectory
def traj(self, mapper):
    est, tr = orig_traj(self, mapper); cap["est"], cap["tracked"] = est, tr; return est, tr
bd.TrajectoryRecorder.trajectory = traj

trk = {k: parse_value(v) for k, v in (s.split("=", 1) for s in a.set)}
out, rows = bd.run(a.path, a.clean, "synthetic", {"method": "auto", **{k: parse_value(v) for k, v in (e.split("=", 1) for e in a.enh)}}, trk, a.max_frames, stereo=False, kind="euroc")
est, tracked = cap["est"], cap["tracked"]
from canopy.sources import open_source
gt = open_source("euroc", a.clean, max_frames=a.max_frames).ground_truth.poses[:len(est)]
res = {k: out.get(k) for k in ("tracked", "ate", "ate_sim3", "scale", "med_inl", "med_ratio", "med_sigma", "med_thr")}
zt = np.concatenate([r["zt"] for r in recs]); rel = np.concatenate([r["rel"] for r in recs])
sky = zt <= 0; r = rel[~sky]; z = zt[~sky]
res["stereo_per_frame"] = float(np.median([r_["n"] for r_ in recs]))
res["sky_frac"] = float(sky.mean())
res["bad10"] = float(np.mean(np.abs(r) > 0.10)); res["bad25"] = float(np.mean(np.abs(r) > 0.25))
res["rel_med"] = float(np.median(r)); res["rel_mean_clip"] = float(np.mean(np.clip(r, -0.5, 0.5)))
r5 = np.concatenate([r_["rel5"] for r_ in recs]); yy = np.concatenate([r_["y"] for r_ in recs])
f5 = np.isfinite(r5)
res["bad10_5x5"] = float(np.mean(np.abs(r5[f5]) > 0.10)); res["med_5x5"] = float(np.median(r5[f5]))
H = float(yy.max()) + 1
for lo, hi in ((0, 5), (5, 10), (10, 20), (20, 200)):
    m = (zt >= lo) & (zt < hi) & f5
    res[f"z{lo}-{hi}_5x5"] = dict(n=int(m.sum()), bad10=round(float(np.mean(np.abs(r5[m]) > 0.1)), 4) if m.any() else None,
                                med=round(float(np.median(r5[m])), 5) if m.any() else None)
for k in range(3):  # image row thirds: a depth bias that changes with the row tilts the pose (pitch)
    m = f5 & (yy >= k * H / 3) & (yy < (k + 1) * H / 3) & (np.abs(r5) < 0.1)
    res[f"rows{k}_5x5_inlier_med"] = round(float(np.median(r5[m])), 5) if m.any() else None
for lo, hi in ((0, 5), (5, 10), (10, 20), (20, 200)):
    m = (z >= lo) & (z < hi)
    res[f"z{lo}-{hi}"] = dict(n=int(m.sum()), bad10=round(float(np.mean(np.abs(r[m]) > 0.1)), 4) if m.any() else None,
                            med=round(float(np.median(r[m])), 5) if m.any() else None)
rot = relative_rotation_errors(est, gt)
res["rot_err_sum_deg"] = [round(float(x), 3) for x in rot.sum(axis=0)]
res["rot_err_abs_mean_deg"] = [round(float(x), 4) for x in np.abs(rot).mean(axis=0)]
# translation: per-frame length ratio and the ATE per world axis
ratios = []
for i in range(1, len(est)):
    de, dg = se3_inv(est[i - 1]) @ est[i], se3_inv(gt[i - 1]) @ gt[i]
    tg = np.linalg.norm(dg[:3, 3])
    if tg > 0.02: ratios.append(np.linalg.norm(de[:3, 3]) / tg)
res["ratio_med"] = float(np.median(ratios)); res["ratio_mean"] = float(np.mean(ratios))
from canopy.metrics import align_trajectory
err = align_trajectory(est[tracked], gt[tracked], with_scale=False)[:, :3, 3] - gt[tracked][:, :3, 3]
res["ate_axis"] = [round(float(x), 4) for x in np.sqrt((err ** 2).mean(axis=0))]
# ATE over the first / second half alone (is it a slow drift or a jump?)
for name, sl in (("first_half", slice(0, len(est) // 2)), ("second_half", slice(len(est) // 2, None))):
    m = tracked.copy(); m[:] = False; m[sl] = tracked[sl]
    res[f"ate_{name}"] = round(float(bd.ape(est[m], gt[m], "se3")["rmse"]), 4)
fa = np.array(state["far"])
res["kp_per_frame"] = float(np.median(fa[:, 0])); res["kp_far_per_frame"] = float(np.median(fa[:, 1]))
res["kp_far_stereo_per_frame"] = float(np.median(fa[:, 2])); res["kp_sky_per_frame"] = float(np.median(fa[:, 3]))
res["far_stereo_frac"] = float(fa[:, 2].sum() / max(fa[:, 1].sum(), 1))
print(json.dumps(res))
if a.out:
    np.savez(a.out, est=est, gt=gt, tracked=tracked, rot=rot)
