#!/usr/bin/env python
"""ATE split by world axis, the Sim(3) scale, and the rotation drift about the camera axes, from
diag_frames.py's --out .npz files:  python docs/results/s14_darkrows/err_axes.py a.npz b.npz ..."""
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))
from canopy.metrics import align_trajectory, ape, ate_sim3  # noqa: E402
from benchmarks.diagnose_drift import relative_rotation_errors  # noqa: E402

for f in sys.argv[1:]:
    d = np.load(f, allow_pickle=True)
    est, gt = d["est"], d["gt"]
    a, s = ape(est, gt, "se3"), ate_sim3(est, gt)
    # SE(3)-aligned residuals per axis: Umeyama alignment without scale
    pe, pg = est[:, :3, 3], gt[:, :3, 3]
    mu_e, mu_g = pe.mean(0), pg.mean(0)
    U, _, Vt = np.linalg.svd((pg - mu_g).T @ (pe - mu_e))
    S = np.eye(3); S[2, 2] = np.sign(np.linalg.det(U @ Vt))
    R = U @ S @ Vt
    res = (R @ (pe - mu_e).T).T + mu_g - pg
    rms = np.sqrt((res ** 2).mean(0)) * 1000
    rot = relative_rotation_errors(est, gt)
    path = np.linalg.norm(np.diff(pg, axis=0), axis=1).sum()
    print(f"{Path(f).stem:14s} ATE {1000*a['rmse']:.2f} mm  sim3 {1000*s['rmse']:.2f} mm scale {s['scale']:.4f} "
          f"rms x/y/z {rms[0]:.1f}/{rms[1]:.1f}/{rms[2]:.1f} mm  path {path:.2f} m  "
          f"summed rot err pitch/yaw/roll {rot[:,0].sum():+.3f}/{rot[:,1].sum():+.3f}/{rot[:,2].sum():+.3f} deg")
