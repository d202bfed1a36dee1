"""ORB-SLAM3 (raw frames) on one degraded cell, N times: tracked %, ATE and the per-frame translation
error of each frame-to-frame motion against the ground truth (the same dt_err as
bench_enhance_diagnose --per-frame prints for Canopy).

    python docs/results/s9_haze/scripts/orb_per_frame.py kitti /work/cache/degraded/kitti-all-g1-b0.06-high-seed0 3 [max_frames]
"""
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[4]
sys.path.insert(0, str(ROOT))

from benchmarks.peers import orbslam3  # noqa: E402
from canopy.frontend.geometry import se3_inv  # noqa: E402
from canopy.metrics import evaluate_trajectory  # noqa: E402
from canopy.sources import open_source  # noqa: E402

kind, path, reps = sys.argv[1], sys.argv[2], int(sys.argv[3])
max_frames = int(sys.argv[4]) if len(sys.argv) > 4 else None
src = open_source(kind, path, max_frames=max_frames)
gt = src.ground_truth
for rep in range(reps):
    res = orbslam3.run_stereo(path, kind, max_frames=max_frames)
    m = evaluate_trajectory(res.trajectory, gt) if res.trajectory is not None and len(res.trajectory) else {}
    print(f"rep {rep}: tracked {res.tracked}/{res.total}  ATE {(m.get('ate') or {}).get('rmse')}", flush=True)
    if res.trajectory is None or not len(res.trajectory):
        continue
    est = {int(np.argmin(np.abs(gt.stamps - s))): P for s, P in zip(res.trajectory.stamps, res.trajectory.poses)}
    errs = []
    for i in range(1, len(gt)):
        if i in est and i - 1 in est:
            de, dg = se3_inv(est[i - 1]) @ est[i], se3_inv(gt.poses[i - 1]) @ gt.poses[i]
            errs.append(f"{i}:{np.linalg.norm(de[:3, 3] - dg[:3, 3]):.3f}")
    print("  dt_err " + " ".join(errs), flush=True)
