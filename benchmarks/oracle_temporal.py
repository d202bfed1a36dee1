#!/usr/bin/env python
"""Oracle bound of motion-compensated temporal averaging on a degraded generated cell (issue 9, s22).

The generated presets carry the renderer's exact poses (ground truth) and left depth
(``mav0/depth0``), so the warp of frame t−k into frame t is known exactly: a pixel p of camera t with
depth Z back-projects to X = Z·K⁻¹p, moves by T_(t−k)←t = T_w(t−k)⁻¹ T_w(t), and projects to p' in
frame t−k (the classic depth-image-based reprojection). Each frame of both cameras is replaced by the
mean over the last N frames of the cell, each warped into frame t that way (bilinear), a sample kept
only where it lands in view and the depth it predicts agrees with frame t−k's own depth within
``--occlusion-tol`` (else occluded: that frame contributes nothing, the current frame always does).
White sensor noise then falls by up to √N, with no motion error: what the tracker gains on such a
folder bounds what any real (flow-based) temporal denoiser can gain.

The right camera's depth is the left depth forward-warped by its disparity
(``canopy.degrade.depth_from_rendered(view="right")``, as the haze of the cell was painted).

    PYTHONPATH=$PWD python benchmarks/oracle_temporal.py --cell /tmp/temporal-cache/dark-rows-150-g1-b0.06-high-seed0-rendered \\
        --n 4 --out /tmp/temporal/oracle/dark-rows-g1-b0.06-high-s0-n4 [--run]

``--run`` then tracks the folder with the grid's in-process loop (``bench_enhance_diagnose.run``: the
actors' ``auto`` enhancement, FAST rule and sensor σ) against the clean preset's ground truth.
"""
from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from canopy.degrade import depth_from_rendered  # noqa: E402
from canopy.frontend.geometry import se3_inv  # noqa: E402
from canopy.sources import open_source  # noqa: E402


def warp_maps(depth_t: np.ndarray, depth_s: np.ndarray, T_s_t: np.ndarray, K: np.ndarray, tol: float):
    """(map_x, map_y, valid) sampling frame s at the exact projection of each pixel of frame t.
    ``depth_*``: Z-depth (m) of the same camera at t and s; ``T_s_t``: pose of t in s's frame."""
    h, w = depth_t.shape
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    z = depth_t.astype(np.float64)
    X = np.stack([(u - cx) / fx * z, (v - cy) / fy * z, z], axis=-1)
    Xs = X @ T_s_t[:3, :3].T + T_s_t[:3, 3]
    zs = Xs[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        us = fx * Xs[..., 0] / zs + cx
        vs = fy * Xs[..., 1] / zs + cy
    valid = (zs > 0.05) & (us >= 0) & (us <= w - 1) & (vs >= 0) & (vs <= h - 1)
    ui = np.clip(np.rint(us), 0, w - 1).astype(np.int64)
    vi = np.clip(np.rint(vs), 0, h - 1).astype(np.int64)
    seen = depth_s[vi, ui].astype(np.float64)
    valid &= np.abs(zs / np.maximum(seen, 1e-6) - 1.0) < tol  # occluded in s: another surface is nearer
    return us.astype(np.float32), vs.astype(np.float32), valid


def load_depth(cell: Path) -> list[np.ndarray]:
    """The renderer's left Z-depth (m) of every frame, sky (0) and beyond 200 m as 200 m (as the haze did)."""
    files = sorted((cell / "mav0" / "depth0" / "data").iterdir())
    out = []
    for f in files:
        d = cv2.imread(str(f), cv2.IMREAD_UNCHANGED).astype(np.float32) / 1000.0
        out.append(np.where(d > 0, np.minimum(d, 200.0), 200.0).astype(np.float32))
    return out


def average_folder(cell: Path, out: Path, n: int, tol: float) -> dict:
    """Write ``cell`` with every frame of both cameras replaced by the exact-warp mean of the last ``n``."""
    src = open_source("euroc", cell)
    cal = src.calibration
    K = np.array([[cal.fx, 0, cal.cx], [0, cal.fy, cal.cy], [0, 0, 1.0]])
    gt = src.ground_truth.poses
    depth_l = load_depth(cell)
    depth_r = [depth_from_rendered(d, cal, view="right") for d in depth_l]
    T_lr = np.eye(4)
    T_lr[0, 3] = cal.baseline  # right camera in the left camera's frame (cam1 T_BS)
    if out.exists():
        shutil.rmtree(out)
    shutil.copytree(cell, out, ignore=shutil.ignore_patterns("*.png"))
    shutil.copytree(cell / "mav0" / "depth0" / "data", out / "mav0" / "depth0" / "data", dirs_exist_ok=True)
    used = []
    for cam, depth, T_c in (("cam0", depth_l, np.eye(4)), ("cam1", depth_r, T_lr)):
        files = sorted((cell / "mav0" / cam / "data").iterdir())
        imgs = [cv2.imread(str(f), cv2.IMREAD_UNCHANGED) for f in files]
        for t in range(len(imgs)):
            acc = imgs[t].astype(np.float32)
            cnt = np.ones(acc.shape, np.float32)
            T_w_t = gt[t] @ T_c
            for s in range(max(0, t - n + 1), t):
                T_s_t = se3_inv(gt[s] @ T_c) @ T_w_t
                mx, my, ok = warp_maps(depth[t], depth[s], T_s_t, K, tol)
                warped = cv2.remap(imgs[s].astype(np.float32), mx, my, cv2.INTER_LINEAR)
                acc += np.where(ok, warped, 0.0)
                cnt += ok
            if cam == "cam0":
                used.append(float(cnt.mean()))
            cv2.imwrite(str(out / "mav0" / cam / "data" / files[t].name),
                        np.clip(np.rint(acc / cnt), 0, 255).astype(np.uint8))
    return {"frames": len(used), "mean_samples_per_pixel": float(np.mean(used))}


def track(cell: Path, folder: Path, max_frames=None) -> dict:
    """Track ``folder`` with the grid's in-process loop (``bench_enhance_diagnose.run``: the actors' ``auto``
    enhancement, FAST rule and sensor σ, configs/synthetic.yaml) against the clean preset's ground truth
    (the sequence ``cell`` was degraded from)."""
    import yaml
    from benchmarks.bench_enhance_diagnose import run
    clean = Path(yaml.safe_load((cell / "DEGRADED.yaml").read_text())["input"])
    res, rows = run(folder, clean, "synthetic", {"method": "auto"}, {}, max_frames, stereo=False, kind="euroc")
    decisions: dict[str, int] = {}
    for r in rows:
        decisions[r["method"]] = decisions.get(r["method"], 0) + 1
    return {"tracked": res["tracked"], "ate": res.get("ate"), "inliers_p50": res.get("med_inl"),
            "sigma_p50": res.get("med_sigma"), "noise_p50": res.get("med_noise"), "decisions": decisions}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cell", required=True, help="a degraded generated cell (bench_degrade_grid's --cells-cache copy)")
    ap.add_argument("--n", type=int, default=4, help="frames averaged (the current one and the N-1 before it)")
    ap.add_argument("--out", required=True)
    ap.add_argument("--occlusion-tol", type=float, default=0.03)
    ap.add_argument("--run", action="store_true", help="track the folder (in process) and print ATE")
    ap.add_argument("--max-frames", type=int, default=None)
    args = ap.parse_args()
    cell, out = Path(args.cell), Path(args.out)
    info = average_folder(cell, out, args.n, args.occlusion_tol) if args.n > 1 else {}
    if args.run:
        info.update(track(cell, out if args.n > 1 else cell, args.max_frames))
    print(json.dumps({"cell": cell.name, "n": args.n, **info}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
