#!/usr/bin/env python
"""Where does a slow rotation drift come from: the tracker's motion-only refinement or local BA? (issue 9)

Runs the degradation grid's in-process loop (``benchmarks/bench_enhance_diagnose.run``: the actors'
pair enhancement, FAST rule and sensor sigma) on a generated cell, recording

* per keyframe its rotation error against the generator's pose (body frame, rotation vector of
  R_true^T R_est in degrees: x pitch, y yaw, z roll) three times: as tracked (the motion-only
  refinement's pose when the keyframe was made), right after the local BA that inserted it, and at
  the end of the run. The tracker's share of the drift is the sum over keyframes of
  (tracked error of keyframe j) − (error of keyframe j−1 as the map held it then); local BA's share
  the rest. (Body-frame errors subtract to first order: the rotation between keyframes is < 3 deg.)
* per frame the last motion-only refinement's inputs, and counterfactual refinements of the same
  matches from the true pose, each reported as its pitch error (deg) against the true pose:
  ``est`` the tracker's; ``true_X`` every map point replaced by its true position (the map's own
  error removed: what is left is the frame's measurement noise); ``mono`` without the u_r terms;
  ``far`` only points beyond ``--far`` m; ``near`` only points closer than that.
  The map's error is taken from the estimated point minus the true point, expressed in the current
  true camera frame (the map's drift up to this frame is in both: ``est`` − ``true_X`` is the map's share).

A landmark's true position: its creating keypoint back-projected with the generator's exact depth
(``mav0/depth0``, nearest surface in a 5x5 window) and the true pose of that frame.

    CANOPY_CACHE_DIR=/work/cache PYTHONPATH=$PWD python benchmarks/diagnose_pitch.py \
        --path /tmp/dimpitch-cache/day-loop-300-g0.15-b0.06-high-seed0-rendered \
        --clean /work/cache/synthetic/day-loop-seed0-full --max-frames 300 [--set tracking.x=v] [--out f.npz]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import bench_enhance_diagnose as bed  # noqa: E402
from diagnose_drift import rotvec  # noqa: E402
from canopy.backend import LocalMapper  # noqa: E402
from canopy.config import parse_setting  # noqa: E402
from canopy.frontend import Tracker  # noqa: E402
from canopy.frontend.geometry import se3_inv, transform  # noqa: E402
from canopy.frontend.pose import refine_pose  # noqa: E402


def body_rot_err(T_est: np.ndarray, T_true: np.ndarray) -> np.ndarray:
    """Rotation vector (deg) of R_true^T R_est: the estimate's rotation error in its own camera frame."""
    return np.degrees(rotvec(T_true[:3, :3].T @ T_est[:3, :3]))


class RecTracker(Tracker):
    """Keeps each frame's last refinement inputs and each landmark's creation."""

    def __init__(self, *a, **k):
        super().__init__(*a, **k)
        self.created, self.frames, self._cur = {}, {}, None

    def track(self, frame, *a, **k):
        self._cur, self._last = frame.index, None
        res = super().track(frame, *a, **k)
        if self._last is not None:  # the matches the tracker kept (3D point, landmark id) after the refinement
            self._last["kept"] = (self._last_matched[0].copy(), self._last_matched[2].copy())
        self.frames[frame.index] = self._last
        return res

    oracle_track_sigma_deg = None   # --oracle-track-up: the exact up in every motion-only refinement too

    def _refine(self, T_cw, X, r, feats, stereo, inliers=None, line_obs=None):
        if self.oracle_track_sigma_deg is not None and self.oracle_up is not None:
            # the tracker's attitude term (tracking.vertical_track_prior's slot); the world's up: the first
            # frame's true up (the tracker's world)
            from canopy.backend.attitude_prior import AttitudePoseTerm
            self._attitude_term = AttitudePoseTerm(self.oracle_up[self._cur], self.oracle_up[0],
                                                   np.radians(self.oracle_track_sigma_deg))
            est = super()._refine(T_cw, X, r, feats, stereo, inliers=inliers, line_obs=line_obs)
        else:
            est = super()._refine(T_cw, X, r, feats, stereo, inliers=inliers, line_obs=line_obs)
        obs = self._stereo_obs if stereo is self._stereo_last else stereo
        self._last = dict(X=np.array(X, float), uv=feats.uv[r].astype(float), ur=obs.u_right[r].astype(float),
                          has_r=obs.valid[r].copy(), octave=feats.octave[r].copy(), T=est.T_cam_world.copy(),
                          inl=est.inliers.copy())
        return est

    oracle_up = None   # (frames, 3) the generator's up in each camera frame (--oracle-up)
    oracle_sigma_deg = float("nan")

    def _make_keyframe(self, frame, feats, stereo, T_wc, matched_ids, **k):
        kf = super()._make_keyframe(frame, feats, stereo, T_wc, matched_ids, **k)
        if self.oracle_up is not None:   # the exact vertical as the keyframe's measured up
            kf.up_cam = self.oracle_up[frame.index].copy()
            kf.up_sigma_deg = self.oracle_sigma_deg
        for i in np.flatnonzero(kf.new_landmark_ids >= 0):
            self.created[int(kf.new_landmark_ids[i])] = (frame.index, float(feats.uv[i, 0]), float(feats.uv[i, 1]))
        return kf


class RecMapper(LocalMapper):
    """Keeps each keyframe's pose as inserted (tracked), after its own local BA, and the poses of every
    keyframe when the next one is inserted."""

    def __init__(self, *a, **k):
        super().__init__(*a, **k)
        self.tracked, self.after_ba, self.prev_then = {}, {}, {}

    def insert_keyframe(self, kf):
        before = self.keyframe_poses()
        if before:
            last = max(before)
            self.prev_then[kf.index] = (last, before[last].copy())
        self.tracked[kf.index] = kf.T_world_cam.copy()
        upd = super().insert_keyframe(kf)
        self.after_ba[kf.index] = self.keyframe_poses()[kf.index].copy()
        return upd


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--path", required=True)
    ap.add_argument("--clean", required=True)
    ap.add_argument("--max-frames", type=int, default=300)
    ap.add_argument("--set", action="append", default=[])
    ap.add_argument("--far", type=float, default=8.0, help="m: near / far split of the counterfactuals")
    ap.add_argument("--out", default=None)
    ap.add_argument("--oracle-up", type=float, default=None, metavar="SIGMA_DEG",
                    help="hand every keyframe the generator's exact up (world z in the camera frame) with this "
                         "sigma and turn mapping.attitude_prior on (docs/notes/s25-attitude.md)")
    ap.add_argument("--oracle-track-up", type=float, default=None, metavar="SIGMA_DEG",
                    help="with --oracle-up: the exact up also in every frame's motion-only refinement")
    ap.add_argument("--no-counterfactuals", action="store_true", help="keyframe rotation errors only")
    args = ap.parse_args()
    sets = [parse_setting(s) for s in args.set]
    holder = {}

    class T_(RecTracker):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            holder["tracker"] = self

    class M_(RecMapper):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            holder["mapper"] = self

    bed.Tracker, bed.LocalMapper = T_, M_
    if args.oracle_up is not None:
        from canopy.sources import open_source
        gt_all = open_source("euroc", args.clean, max_frames=args.max_frames).ground_truth.poses
        # the generator's world is z up (canopy/synthetic/trajectories.py): up_cam = R_world_cam^T e_z
        T_.oracle_up = np.array([g[:3, :3].T @ np.array([0.0, 0.0, 1.0]) for g in gt_all])
        T_.oracle_sigma_deg = args.oracle_up
        T_.oracle_track_sigma_deg = args.oracle_track_up
        sets.append(("mapping", "attitude_prior", True))
    out, _ = bed.run(args.path, args.clean, "synthetic", {}, {f: v for s, f, v in sets if s == "tracking"},
                     args.max_frames, stereo=False, kind="euroc",
                     map_sets={f: v for s, f, v in sets if s == "mapping"})
    tr, mp = holder["tracker"], holder["mapper"]
    from canopy.sources import open_source
    src = open_source("euroc", args.clean, max_frames=args.max_frames)
    gt = src.ground_truth.poses[:args.max_frames]
    G0 = se3_inv(gt[0])
    gtl = np.array([G0 @ g for g in gt])       # true T_world_cam in the tracker's world
    print(f"ATE {1e3 * out['ate']:.3f} mm  (Sim3 {1e3 * out['ate_sim3']:.3f}, scale {out['scale']:.5f})")

    # --- 1. keyframes: tracker's vs local BA's share
    final = mp.keyframe_poses()
    kfs = sorted(mp.tracked)
    trk_inc, ba_inc, rows, incs = np.zeros(3), np.zeros(3), [], []
    for k in kfs:
        e_tr = body_rot_err(mp.tracked[k], gtl[k])
        e_ba = body_rot_err(mp.after_ba[k], gtl[k])
        e_fin = body_rot_err(final[k], gtl[k])
        if k in mp.prev_then:
            p, Tp = mp.prev_then[k]
            d_tr = e_tr - body_rot_err(Tp, gtl[p])
            d_ba = e_fin - e_tr - (body_rot_err(final[p], gtl[p]) - body_rot_err(Tp, gtl[p]))
            trk_inc += d_tr
            ba_inc += d_ba
            incs.append((k, *d_tr, *d_ba))
        rows.append((k, *e_tr, *e_ba, *e_fin))
    rows = np.array(rows)
    e_last = rows[-1, 7:10]
    print(f"keyframes {len(kfs)}; final rotation error of the last keyframe (deg, x pitch / y yaw / z roll): "
          f"{e_last[0]:+.3f} {e_last[1]:+.3f} {e_last[2]:+.3f}")
    print(f"  tracker's increments summed : {trk_inc[0]:+.3f} {trk_inc[1]:+.3f} {trk_inc[2]:+.3f}")
    print(f"  local BA's corrections summed: {ba_inc[0]:+.3f} {ba_inc[1]:+.3f} {ba_inc[2]:+.3f}")
    incs = np.array(incs)
    for name, col in (("tracker", 1), ("local BA", 4)):
        q = np.percentile(incs[:, col], [10, 50, 90])
        print(f"  {name} pitch increments per keyframe: p10 / p50 / p90 {q[0]:+.4f} / {q[1]:+.4f} / {q[2]:+.4f}, "
              f"negative {100 * np.mean(incs[:, col] < 0):.0f} %")
    print(f"  (first keyframe's error {rows[0, 7]:+.3f} {rows[0, 8]:+.3f} {rows[0, 9]:+.3f})")
    ups = getattr(mp, "attitude", None)
    if ups is not None and ups.up_cam:   # the measured ups the attitude prior used, against the generator's
        ks = sorted(ups.up_cam)
        true_up = np.array([gt[k][:3, :3].T @ np.array([0.0, 0.0, 1.0]) for k in ks])
        meas = np.array([ups.up_cam[k] for k in ks])
        ang = np.degrees(np.arccos(np.clip(np.sum(meas * true_up, axis=1), -1, 1)))
        sig = np.degrees([ups.sigma[k] for k in ks])
        print(f"  measured up on {len(ks)} of {len(kfs)} keyframes: error p50 / p90 {np.median(ang):.3f} / "
              f"{np.percentile(ang, 90):.3f} deg, sigma p50 {np.median(sig):.3f} deg, error / sigma p50 "
              f"{np.median(ang / sig):.2f}")

    if args.no_counterfactuals:
        return 0
    # --- 2. per-frame counterfactual refinements from the true pose
    dfiles = sorted((Path(args.clean) / "mav0" / "depth0" / "data").iterdir())
    cache = {}

    def fg(i):
        if i not in cache:
            D = cv2.imread(str(dfiles[i]), cv2.IMREAD_UNCHANGED).astype(np.float32) / 1000.0
            D[D <= 0] = np.inf
            cache[i] = cv2.erode(D, np.ones((5, 5), np.uint8))
        return cache[i]

    c, p = tr.calib, tr.params
    ids_of = {}
    for lid, (fi, u, v) in tr.created.items():
        D = fg(fi)
        z = float(D[int(np.clip(round(v), 0, D.shape[0] - 1)), int(np.clip(round(u), 0, D.shape[1] - 1))])
        if np.isfinite(z):
            Pc = np.array([[(u - c.cx) * z / c.fx, (v - c.cy) * z / c.fy, z]])
            ids_of[lid] = transform(gtl[fi], Pc)[0]
    cf_rows = []
    for i in range(1, len(gtl)):
        rec = tr.frames.get(i)
        if rec is None:
            continue
        X, uv, ur, hr, octv, inl = rec["X"], rec["uv"], rec["ur"], rec["has_r"], rec["octave"], rec["inl"]
        # the landmark ids of these points, looked up by value among the matches the tracker kept
        Xt = np.full_like(X, np.nan)
        key = {tuple(x): int(l) for x, l in zip(*rec.get("kept", (np.zeros((0, 3)), [])))}
        for j, x in enumerate(X):
            lid = key.get(tuple(x), -1)
            if lid in ids_of:
                Xt[j] = ids_of[lid]
        Ttrue = se3_inv(gtl[i])
        sig = p.pixel_sigma * tr.scale_factors[octv]
        meas = np.column_stack([uv, ur])
        z_true = transform(Ttrue, np.where(np.isfinite(Xt), Xt, X))[:, 2]

        def solve(Xs, sel, right):
            if sel.sum() < 8:
                return np.full(3, np.nan)
            e = refine_pose(Ttrue, Xs[sel], meas[sel], (hr & right)[sel], sig[sel], c, p.pose_opt_rounds,
                            p.pose_opt_iterations, p.chi2_mono, p.chi2_stereo)
            return body_rot_err(se3_inv(e.T_cam_world), gtl[i])
        kn = inl & np.isfinite(Xt[:, 0])
        yes = np.ones(len(X), bool)
        row = [i, inl.sum(), kn.sum(), (inl & hr).sum(), (inl & (z_true > args.far)).sum()]
        row += list(body_rot_err(se3_inv(rec["T"]), gtl[i]))
        row += list(solve(X, inl, yes)) + list(solve(Xt, kn, yes)) + list(solve(X, inl, ~yes))
        row += list(solve(X, inl & (z_true > args.far), yes)) + list(solve(X, inl & (z_true <= args.far), yes))
        row += list(solve(Xt, kn, ~yes))
        # the map's point error in the true camera frame: vertical (y, down) and depth (z) medians, near band
        if kn.any():
            dP = transform(Ttrue, X[kn]) - transform(Ttrue, Xt[kn])
            row += [float(np.median(dP[:, 1])), float(np.median(dP[:, 2]))]
        else:
            row += [np.nan, np.nan]
        cf_rows.append(row)
    cf = np.array(cf_rows, float)
    names = ["est_abs", "est", "true_X", "mono", "far", "near", "true_X_mono"]
    print(f"\nper-frame counterfactual refinements from the true pose: rotation error (deg, median over frames "
          f"| mean), x pitch / y yaw / z roll; far/near split {args.far} m")
    print(f"  inliers p50 {np.median(cf[:, 1]):.0f}, with a true point {np.median(cf[:, 2]):.0f}, stereo "
          f"{np.median(cf[:, 3]):.0f}, far {np.median(cf[:, 4]):.0f}")
    for n_, name in enumerate(names):
        blk = cf[:, 5 + 3 * n_: 8 + 3 * n_]
        print(f"  {name:12s} " + "  ".join(f"{np.nanmedian(blk[:, a]):+.4f} | {np.nanmean(blk[:, a]):+.4f}"
                                          for a in range(3)))
    print(f"  map point error in the true camera (m, median over frames of per-frame medians): "
          f"y(down) {np.nanmedian(cf[:, -2]):+.4f}  z {np.nanmedian(cf[:, -1]):+.4f}")
    if args.out:
        np.savez(args.out, kf=rows, inc=incs, cf=cf, cf_names=np.array(names))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
