#!/usr/bin/env python
"""Are the tracker's inlier matches true correspondences? Generated sequences only (exact depth + poses).

Runs the same in-process tracking -> local mapping loop as ``benchmarks/diagnose_drift.py`` and, per frame,
takes the matches the final motion-only refinement kept (3D map point, keypoint, its stereo u_right).
Against the generator's ground truth (``mav0/depth0``, exact depth of cam0; the true poses):

* a landmark's *physical point*: its creating keyframe's keypoint back-projected with the exact depth at
  that pixel and the true pose of that frame;
* a match is a **true correspondence** when that point, projected with the true pose of the current frame,
  lands within ``--tol`` px (times the keypoint's octave scale) of the matched keypoint;
* the landmark's **position error**: the map's point (the estimate, in the first camera's frame, which is the
  tracker's world) against the physical point;
* the current frame's **stereo depth error** for matches measured with a stereo u_right.

Counterfactual poses on the same matches (``refine_pose`` from the true pose, the tracker's settings), each
compared with the true pose (translation error, mm): ``est`` the tracker's; ``true_X`` the map points replaced
by their physical points; ``true_corr`` only true correspondences; ``mono`` no u_right terms;
``true_X_mono`` both; ``surface`` / ``true_X_surface`` only landmarks created off occluding contours (their
5x5 exact depth within 5 %; nan when fewer than 6). Which replacement removes the error says where it
comes from. A contour keypoint has no fixed physical point (the contour slides over the surface as the
view changes): its "physical point" is the foreground surface point its creating keypoint saw.

``--oracle-velocity`` / ``--oracle-stereo`` replace the constant-velocity prediction / every stereo depth
with the truth (diagnoses, not methods); ``--auto-enhance`` runs each image through ``auto_treat`` first
(the dark clean presets); ``--pipeline-enhance`` runs each pair through the pipeline's enhancement, with the
actors' FAST arguments and noise sigma for the tracker (the dim grid cells; docs/notes/s24-dimhaze.md). docs/notes/s17-darkrows.md has the dark-rows g1-b0.06-high figures.

    PYTHONPATH=$PWD CANOPY_CACHE_DIR=/work/cache python benchmarks/diagnose_correspondences.py \
        --path /work/cache/degraded/dark-rows-400-g1-b0.06-high-seed0-rendered --max-frames 150 --out /tmp/c.npz
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import diagnose_drift as dd  # noqa: E402
from canopy.frontend import Tracker  # noqa: E402
from canopy.frontend.geometry import project_stereo, se3_inv, transform  # noqa: E402
from canopy.frontend.pose import refine_pose  # noqa: E402


class RecordingTracker(Tracker):
    """A Tracker that keeps, per frame, the last refinement's inputs and result, and each landmark's
    creation (frame, keypoint, stereo depth)."""

    def __init__(self, *a, **k):
        super().__init__(*a, **k)
        self.created: dict[int, tuple[int, float, float, float]] = {}
        self.last_refine = None
        self.frame_stereo = None

    def _refine(self, T_cw, X, r, feats, stereo, inliers=None, line_obs=None):
        est = super()._refine(T_cw, X, r, feats, stereo, inliers=inliers, line_obs=line_obs)
        self.last_refine = (np.array(X, float), np.array(r), feats.uv[r].astype(np.float64),
                            stereo.u_right[r].astype(np.float64), stereo.valid[r].copy(), feats.octave[r].copy(),
                            est.T_cam_world.copy(), est.inliers.copy(), np.array(T_cw, float))
        return est

    def _make_keyframe(self, frame, feats, stereo, T_wc, matched_ids, **k):
        kf = super()._make_keyframe(frame, feats, stereo, T_wc, matched_ids, **k)
        idx = np.flatnonzero(kf.new_landmark_ids >= 0)
        for i in idx:
            self.created[int(kf.new_landmark_ids[i])] = (frame.index, float(feats.uv[i, 0]), float(feats.uv[i, 1]),
                                                        float(stereo.depth[i]))
        return kf

    oracle_depth = None   # frame index -> exact depth (5x5 foreground min), set by main for --oracle-stereo

    def _stereo(self, stereo, timings):
        out = super()._stereo(stereo, timings)
        if self.oracle_depth is None or getattr(self, "_oracle_out", None) is out:
            return out
        # a diagnosis, not a method: every stereo match's depth replaced by the exact depth at its keypoint
        # (the nearest surface in its 5x5 window); matches on sky keep none
        from canopy.frontend.stereo import StereoMatches
        uv = self._contour_inputs[2].uv
        D = self.oracle_depth(self._oracle_frame)
        h, w = D.shape
        x = np.clip(np.round(uv[:, 0]).astype(int), 0, w - 1)
        y = np.clip(np.round(uv[:, 1]).astype(int), 0, h - 1)
        z = D[y, x]
        ok = out.valid & np.isfinite(z) & (z > 0)
        depth = np.where(ok, z, -1.0).astype(np.float32)
        u_right = np.where(ok, uv[:, 0] - self.calib.bf / np.where(ok, z, 1.0), -1.0).astype(np.float32)
        new = StereoMatches(u_right, depth, out.n_candidates, on_contour=out.on_contour)
        self._oracle_out = new
        self._stereo_last, self._stereo_obs = new, self._bearing_only_far(new)
        return new

    def track(self, frame, *a, **k):
        self._oracle_frame = frame.index
        self.last_refine = None
        self.frame_stereo = None
        res = super().track(frame, *a, **k)
        return res


def edge_normals(image: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per keypoint: the unit normal of the local edge (the structure tensor's dominant eigenvector,
    gradients at sigma 1, window sigma 3) and the eigenvalue ratio lambda_min / lambda_max (0: a straight
    edge, 1: a blob or a corner)."""
    img = cv2.GaussianBlur(image.astype(np.float32), (0, 0), 1.0)
    gx = cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=3)
    jxx, jxy, jyy = (cv2.GaussianBlur(a, (0, 0), 3.0) for a in (gx * gx, gx * gy, gy * gy))
    h, w = img.shape
    x = np.clip(np.round(uv[:, 0]).astype(int), 0, w - 1)
    y = np.clip(np.round(uv[:, 1]).astype(int), 0, h - 1)
    a, b, c = jxx[y, x].astype(float), jxy[y, x].astype(float), jyy[y, x].astype(float)
    tr, det = a + c, a * c - b * b
    disc = np.sqrt(np.maximum(tr * tr / 4 - det, 0.0))
    l1, l2 = tr / 2 + disc, tr / 2 - disc
    theta = 0.5 * np.arctan2(2 * b, a - c)  # the dominant eigenvector's angle
    return np.stack([np.cos(theta), np.sin(theta)], axis=1), l2 / np.maximum(l1, 1e-12)


def refine_anisotropic(T_cw, X, uv, sigma, normals, ratio, calib, along_factor, edge_ratio=0.2, iterations=10):
    """Monocular Gauss-Newton on (u, v) residuals whose sigma along an edge-like keypoint's edge
    (eigenvalue ratio < ``edge_ratio``) is ``along_factor`` x its sigma across it (a diagnosis of how much
    the contour keypoints' sliding costs: along_factor 1 = isotropic)."""
    from canopy.frontend.geometry import se3_exp, stereo_pose_jacobian
    n_ = normals
    t_ = np.stack([-n_[:, 1], n_[:, 0]], axis=1)
    s_t = np.where(ratio < edge_ratio, along_factor, 1.0) * sigma
    # W = n n^T / s^2 + t t^T / s_t^2 per point
    W = (n_[:, :, None] * n_[:, None, :]) / (sigma ** 2)[:, None, None] + \
        (t_[:, :, None] * t_[:, None, :]) / (s_t ** 2)[:, None, None]
    T = T_cw.copy()
    for _ in range(iterations):
        pred, Pc = project_stereo(T, X, calib)
        r = uv - pred[:, :2]
        J = stereo_pose_jacobian(Pc, calib)[:, :2, :]
        JW = np.einsum("nki,nkl->nil", J, W)
        H = np.einsum("nil,nlj->ij", JW, J)
        g = np.einsum("nil,nl->i", JW, r)
        try:
            dx = np.linalg.solve(H, g)
        except np.linalg.LinAlgError:
            break
        T = se3_exp(dx) @ T
        if np.linalg.norm(dx) < 1e-7:
            break
    return T


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--path", required=True)
    ap.add_argument("--max-frames", type=int, default=150)
    ap.add_argument("--set", action="append", default=[])
    ap.add_argument("--tol", type=float, default=3.0, help="px (x octave scale) for a true correspondence")
    ap.add_argument("--out", default=None)
    ap.add_argument("--along-factor", type=float, default=0.0,
                    help="diagnosis: also solve each frame's pose (monocular) with an edge keypoint's sigma along "
                         "its edge this many times its sigma across (and isotropically, for comparison)")
    ap.add_argument("--auto-enhance", action="store_true",
                    help="each image through canopy.enhance.auto.auto_treat first (per image, not the pipeline's "
                         "pair treatment; for the dark clean presets, whose frames auto enhances)")
    ap.add_argument("--pipeline-enhance", action="store_true",
                    help="each pair through the pipeline's enhancement (bench_enhance_diagnose.enhance_pair: the "
                         "synthetic config's auto, the pair treatment) and the tracker given the actors' FAST "
                         "arguments and the enhancement's noise sigma (the fill-in gate): the dim grid cells")
    ap.add_argument("--oracle-stereo", action="store_true",
                    help="diagnosis: every stereo depth replaced by the exact (foreground) depth at its keypoint")
    ap.add_argument("--oracle-velocity", action="store_true",
                    help="diagnosis: predict each frame with the true motion from the previous one")
    ap.add_argument("--print-frames", type=int, default=30)
    args = ap.parse_args()

    depth_files = sorted((Path(args.path) / "mav0" / "depth0" / "data").iterdir())

    def exact_depth(i):
        return cv2.imread(str(depth_files[i]), cv2.IMREAD_UNCHANGED).astype(np.float32) / 1000.0

    rows = []          # per match
    frame_rows = []    # per frame
    state = {}

    orig_tracker = dd.Tracker

    class Hooked(RecordingTracker):
        pass

    dd.Tracker = Hooked
    orig_open = dd.open_source
    if args.auto_enhance:
        from canopy.enhance.auto import auto_treat
        from canopy.enhance.params import EnhanceParams
        ep = EnhanceParams()

        def open_enhanced(*a, **k):
            src = orig_open(*a, **k)
            raw = src.frame
            src.frame = lambda i: dataclasses.replace(raw(i), left=auto_treat(raw(i).left, ep)[0],
                                                      right=auto_treat(raw(i).right, ep)[0])
            return src
        dd.open_source = open_enhanced
    enhanced = {}   # frame index -> the tracker's keyword arguments for that enhanced pair
    if args.pipeline_enhance:
        from bench_enhance_diagnose import actor_fast, enhance_pair
        from canopy.config import load_run_config
        from canopy.enhance import make_enhancer
        cfg = load_run_config("synthetic")
        ep = dataclasses.replace(cfg.enhancement, method="auto")
        enhancer = make_enhancer(ep)

        def open_pipeline(*a, **k):
            src = orig_open(*a, **k)
            raw = src.frame

            def frame(i):
                f = raw(i)
                le, re, info = enhance_pair(enhancer, f.left, f.right)
                enhanced[f.index] = dict(actor_fast(ep, info, le, cfg.tracking.n_features),
                                         sensor_sigma=info["noise_sigma"])
                return dataclasses.replace(f, left=le, right=re)
            src.frame = frame
            return src
        dd.open_source = open_pipeline
    if args.oracle_stereo:
        fg_cache = {}

        def fg_depth(i):
            if i not in fg_cache:
                D = exact_depth(i)
                D[D <= 0] = np.inf
                fg_cache.clear()
                fg_cache[i] = cv2.erode(D, np.ones((5, 5), np.uint8))
            return fg_cache[i]
        Hooked.oracle_depth = staticmethod(fg_depth)
    # the loop of diagnose_drift.run, with a per-frame hook through Tracker.track
    holder = {}

    gt_all = None
    from canopy.sources import open_source as _open
    images = _open("euroc", args.path, max_frames=args.max_frames) if args.along_factor > 0 else None
    if args.oracle_velocity:
        from canopy.sources import open_source
        gt_all = open_source("euroc", args.path, max_frames=args.max_frames).ground_truth.poses

    def track_hook(self, frame, *a, **k):
        if gt_all is not None and frame.index > 0 and getattr(self, "_velocity_valid", False):
            # a diagnosis, not a method: the constant-velocity prediction replaced by the true motion
            self._velocity = se3_inv(gt_all[frame.index - 1]) @ gt_all[frame.index]
        res = RecordingTracker.track(self, frame, *a, **{**enhanced.get(frame.index, {}), **k})
        holder.setdefault("tracker", self)
        state[frame.index] = (self.last_refine, self._last_matched, res)
        return res

    Hooked.track = track_hook
    d = dd.run("synthetic", args.path, args.max_frames, args.set)
    dd.Tracker = orig_tracker
    dd.open_source = orig_open
    tr = holder["tracker"]
    gt = d["gt"]
    calib = tr.calib
    G0inv = se3_inv(gt[0])
    gt_local = np.array([G0inv @ g for g in gt])      # true T_world_cam in the tracker's world (cam 0)
    depth_cache = {}

    def dmap(i):
        if i not in depth_cache:
            depth_cache[i] = exact_depth(i)
        return depth_cache[i]

    win_cache = {}

    def window(i):
        """(exact depth, its 5x5 min over non-sky, 5x5 max with sky as infinity) of frame i."""
        if i not in win_cache:
            D = dmap(i).copy()
            D[D <= 0] = np.inf
            k = np.ones((5, 5), np.uint8)
            win_cache[i] = (D, cv2.erode(D, k), cv2.dilate(D, k))
        return win_cache[i]

    def physical(lid):
        """The landmark's physical point: its creating keypoint back-projected with the nearest exact depth
        in its 5x5 window (the foreground side of a silhouette), and whether that window is one surface
        (max depth within 5 % of min depth)."""
        c, u, v, zs = tr.created[lid]
        D, lo, hi = window(c)
        h, w = D.shape
        x, y = int(np.clip(round(u), 0, w - 1)), int(np.clip(round(v), 0, h - 1))
        z = float(lo[y, x])
        surface = bool(hi[y, x] < 1.05 * lo[y, x])
        if not np.isfinite(z):
            return None, c, zs, z, False
        Pc = np.array([(u - calib.cx) * z / calib.fx, (v - calib.cy) * z / calib.fy, z])
        return transform(gt_local[c], Pc[None])[0], c, zs, z, surface

    p = tr.params
    sigma_of = lambda octv: p.pixel_sigma * tr.scale_factors[octv]  # noqa: E731
    hdr = ("frame  inl surf surfcur true%  |Xerr|p50mm  Xdepth%p50  stereo%p50(cur)  step_est/true  "
           "terr_mm: est true_X "
           "true_corr mono true_X_mono surface true_X_surface")
    print(hdr)
    for i in range(1, len(gt)):
        if i not in state or state[i][0] is None:
            continue
        (X, r, uv, ur, has_r, octv, T_est, inl, T_start), (Xk, _, idk), res = state[i]
        key = {tuple(x): int(l) for x, l in zip(Xk, idk)}
        ids = np.array([key.get(tuple(x), -1) for x in X])
        T_true_cw = se3_inv(gt_local[i])
        n = len(X)
        Xtrue = np.full((n, 3), np.nan)
        created_frame = np.full(n, -1)
        z_created_stereo = np.full(n, np.nan)
        z_created_true = np.full(n, np.nan)
        surf_created = np.zeros(n, bool)
        for j in range(n):
            if ids[j] >= 0 and ids[j] in tr.created:
                P, c, zs, zt, sf = physical(int(ids[j]))
                created_frame[j], z_created_stereo[j], z_created_true[j], surf_created[j] = c, zs, zt, sf
                if P is not None:
                    Xtrue[j] = P
        known = np.isfinite(Xtrue[:, 0])
        proj_true, Pc_true = project_stereo(T_true_cw, np.where(known[:, None], Xtrue, 0.0), calib)
        reproj = np.linalg.norm(proj_true[:, :2] - uv, axis=1)
        scale = tr.scale_factors[octv]
        true_corr = known & (reproj <= args.tol * scale) & (Pc_true[:, 2] > 0)
        xerr = np.linalg.norm(X - Xtrue, axis=1)
        # the map point's depth error along its creating ray (relative)
        depth_rel = z_created_stereo / z_created_true - 1.0
        # current stereo depth error at the keypoint
        D, lo, hi = window(i)
        h, w = D.shape
        xi = np.clip(np.round(uv[:, 0]).astype(int), 0, w - 1)
        yi = np.clip(np.round(uv[:, 1]).astype(int), 0, h - 1)
        zt_cur = np.where(np.isfinite(lo[yi, xi]), lo[yi, xi], 0.0)
        surf_cur = hi[yi, xi] < 1.05 * lo[yi, xi]
        disp = uv[:, 0] - ur
        z_cur = np.where(has_r & (disp > 0), calib.bf / np.maximum(disp, 1e-9), np.nan)
        cur_rel = z_cur / np.where(zt_cur > 0, zt_cur, np.nan) - 1.0

        def solve(Xs, sel, right):
            meas = np.column_stack([uv[sel], ur[sel]])
            e = refine_pose(T_true_cw, Xs[sel], meas, (has_r & right)[sel], sigma_of(octv[sel]), calib,
                            p.pose_opt_rounds, p.pose_opt_iterations, p.chi2_mono, p.chi2_stereo)
            return e.T_cam_world

        def terr(T_cw):
            return 1e3 * float(np.linalg.norm(se3_inv(T_cw)[:3, 3] - gt_local[i][:3, 3]))

        T_est_wc = se3_inv(T_est)
        step_est = np.linalg.norm(T_est_wc[:3, 3] - d["online"][i - 1][:3, 3])
        step_true = np.linalg.norm(gt_local[i][:3, 3] - gt_local[i - 1][:3, 3])
        yes = np.ones(n, bool)
        used = inl
        cf = {}
        cf["est"] = terr(T_est)
        kn = used & known
        cf["true_X"] = terr(solve(Xtrue, kn, yes)) if kn.sum() >= 6 else np.nan
        tc = used & true_corr
        cf["true_corr"] = terr(solve(X, tc, yes)) if tc.sum() >= 6 else np.nan
        su = used & surf_created
        cf["surface"] = terr(solve(X, su, yes)) if su.sum() >= 6 else np.nan
        cf["true_X_surface"] = terr(solve(Xtrue, su & known, yes)) if (su & known).sum() >= 6 else np.nan
        cf["mono"] = terr(solve(X, used, ~yes)) if used.sum() >= 6 else np.nan
        cf["true_X_mono"] = terr(solve(Xtrue, kn, ~yes)) if kn.sum() >= 6 else np.nan
        if images is not None:
            normals, ratio = edge_normals(images.frame(i).left, uv)
            sg = sigma_of(octv)
            for name, Xs, sel in (("iso", X, used), ("true_X_iso", Xtrue, used & known)):
                af = 1.0
                cf[name] = terr(refine_anisotropic(T_true_cw, Xs[sel], uv[sel], sg[sel], normals[sel], ratio[sel],
                                                   calib, af)) if sel.sum() >= 6 else np.nan
                cf[name.replace("iso", "aniso")] = terr(refine_anisotropic(
                    T_true_cw, Xs[sel], uv[sel], sg[sel], normals[sel], ratio[sel], calib,
                    args.along_factor)) if sel.sum() >= 6 else np.nan
            cf["edge_share"] = float((ratio[used] < 0.2).mean())
        ui = used
        fr = dict(frame=i, n_inl=int(ui.sum()), n_known=int((ui & known).sum()),
                  true_frac=float(true_corr[ui & known].mean()) if (ui & known).any() else np.nan,
                  xerr_p50=float(np.nanmedian(xerr[ui & known])) * 1e3 if (ui & known).any() else np.nan,
                  depth_rel_p50=float(np.nanmedian(depth_rel[ui & known])) if (ui & known).any() else np.nan,
                  cur_rel_p50=float(np.nanmedian(cur_rel[ui])) if np.isfinite(cur_rel[ui]).any() else np.nan,
                  n_stereo_inl=int((ui & has_r).sum()), n_surf=int((ui & surf_created).sum()),
                  n_surf_cur=int((ui & surf_cur).sum()),
                  step_ratio=step_est / max(step_true, 1e-9), step_true=step_true, **cf)
        frame_rows.append(fr)
        for j in np.flatnonzero(ui):
            rows.append((i, ids[j], created_frame[j], octv[j], reproj[j], true_corr[j], xerr[j], depth_rel[j],
                         cur_rel[j], has_r[j], z_created_true[j], zt_cur[j], uv[j, 0], uv[j, 1], surf_created[j],
                         surf_cur[j], z_created_stereo[j], uv[j, 0] - proj_true[j, 0], uv[j, 1] - proj_true[j, 1]))
        if len(frame_rows) <= args.print_frames or i % 10 == 0:
            print(f"{i:5d} {fr['n_inl']:4d} {fr['n_surf']:4d} {fr['n_surf_cur']:4d} "
                  f"{100 * fr['true_frac']:5.0f}  {fr['xerr_p50']:9.0f}  "
                  f"{100 * fr['depth_rel_p50']:+8.1f}  {100 * fr['cur_rel_p50']:+8.1f}  "
                  f"{fr['step_ratio']:6.2f} ({1e3 * step_true:4.1f}mm)  "
                  f"{cf['est']:6.1f} {cf['true_X']:6.1f} {cf['true_corr']:6.1f} {cf['mono']:6.1f} "
                  f"{cf['true_X_mono']:6.1f} {cf['surface']:6.1f} {cf['true_X_surface']:6.1f}")
    dd.summarise(d, 10)
    if args.out:
        cols = ("frame", "lid", "created", "octave", "reproj", "true_corr", "xerr", "depth_rel", "cur_rel", "has_r",
                "z_created_true", "z_cur_true", "u", "v", "surf_created",
                "surf_cur", "z_created_stereo", "res_u", "res_v")
        np.savez(args.out, matches=np.array(rows, float), match_cols=np.array(cols),
                 frames=np.array([[f[k] for k in frame_rows[0]] for f in frame_rows], float),
                 frame_cols=np.array(list(frame_rows[0])), final=d["final"], gt=d["gt"], online=d["online"])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
