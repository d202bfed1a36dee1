"""Per-frame diagnosis of one KITTI cell (s24-kittinoisy): bench_enhance_diagnose's in-process loop, plus per
frame the rotation / translation error of the frame-to-frame motion against ground truth and the number of
tracked (pose-inlier) landmarks farther than 30 m / 15 m in the current camera.

    CANOPY_CACHE_DIR=/work/cache PYTHONPATH=$PWD python docs/results/s24_kittinoisy/diag_far.py \
        --path /tmp/kittinoisy-cache/kitti-all-g1-b0.06-high-seed0-stereo-sky [--set tracking.x=y ...] --out F.json
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))
import benchmarks.bench_enhance_diagnose as bed  # noqa: E402
from canopy.config import parse_value  # noqa: E402

FAR = []


class RecordingTracker(bed.Tracker):
    def track(self, frame, **kw):
        res = super().track(frame, **kw)
        depths = np.zeros(0)
        if res.status in ("ok", "init"):
            X = self._last_matched[0]
            if len(X):
                T_cw = np.linalg.inv(res.T_world_cam)
                depths = (X @ T_cw[:3, :3].T + T_cw[:3, 3])[:, 2]
        FAR.append({"n": int(len(depths)), "far30": int((depths > 30).sum()), "far15": int((depths > 15).sum()),
                    "n_stereo": int(res.n_stereo), "n_matches": int(res.n_matches), "kf": bool(res.is_keyframe),
                    "T_track": res.T_world_cam.tolist()})
        return res


def rot_deg(R):
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--path", required=True)
    ap.add_argument("--set", action="append", default=[])
    ap.add_argument("--out", required=True)
    a = ap.parse_args()
    trk = {k.split(".", 1)[-1]: parse_value(v) for k, v in (s.split("=", 1) for s in a.set)}
    bed.Tracker = RecordingTracker
    clean = bed.BUNDLED_DATA["kitti"]
    # keep the trajectory: run() rebuilds it; recompute per-frame errors from its est via a second hook
    captured = {}
    orig_traj = bed.TrajectoryRecorder.trajectory

    def traj(self, mapper):
        est, tracked = orig_traj(self, mapper)
        captured["est"] = est
        return est, tracked
    bed.TrajectoryRecorder.trajectory = traj
    out, rows = bed.run(a.path, clean, "kitti", {}, trk, None, False, False)
    gt = bed.open_source("kitti", clean).ground_truth.poses[: len(captured["est"])]
    est = captured["est"]
    per = []
    for i in range(len(est)):
        r = dict(FAR[i])
        if i > 0:
            de = np.linalg.inv(est[i - 1]) @ est[i]
            dg = np.linalg.inv(gt[i - 1]) @ gt[i]
            r["drot"] = rot_deg(de[:3, :3].T @ dg[:3, :3])
            r["dt"] = float(np.linalg.norm(de[:3, 3] - dg[:3, 3]))
            # the same for the pose as tracking returned it (before local BA moved its keyframes)
            Tp, Tc = np.array(FAR[i - 1]["T_track"]), np.array(FAR[i]["T_track"])
            dtr = np.linalg.inv(Tp) @ Tc
            r["drot_track"] = rot_deg(dtr[:3, :3].T @ dg[:3, :3])
            r["dt_track"] = float(np.linalg.norm(dtr[:3, 3] - dg[:3, 3]))
        # absolute rotation error after aligning the first pose
        Ra = (np.linalg.inv(est[0]) @ est[i])[:3, :3]
        Rg = (np.linalg.inv(gt[0]) @ gt[i])[:3, :3]
        r["rot_abs"] = rot_deg(Ra.T @ Rg)
        per.append(r)
    summ = {k: out.get(k) for k in ("tracked", "ate", "ate_sim3", "scale")}
    d = np.array([p.get("drot", np.nan) for p in per[1:]])
    summ.update(drot_rms=float(np.sqrt(np.nanmean(d ** 2))), dt_rms=float(np.sqrt(np.nanmean([p["dt"] ** 2 for p in per[1:]]))),
                far30_med=float(np.median([p["far30"] for p in per])), far15_med=float(np.median([p["far15"] for p in per])),
                inl_med=float(np.median([p["n"] for p in per])), rot_abs_end=per[-1]["rot_abs"],
                rot_abs_max=max(p["rot_abs"] for p in per))
    Path(a.out).write_text(json.dumps({"summary": summ, "frames": per, "est": est.tolist(), "gt": np.asarray(gt).tolist()}))
    print("SUMMARY", json.dumps({k: (round(v, 5) if isinstance(v, float) else v) for k, v in summ.items()}))


if __name__ == "__main__":
    main()
