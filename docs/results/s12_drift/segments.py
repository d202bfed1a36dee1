#!/usr/bin/env python
"""Per-segment summary of ``benchmarks/diagnose_drift.py --out`` records: whole-run ATE (SE(3)) and
its rms per world axis, and per segment (rows / U-turns of the generated day-loop) the rotation
error picked up from its first to its last frame (rotation vector of (gt_s^-1 gt_e)^T (est_s^-1 est_e)
in the first frame's camera axes: x pitch / y yaw / z roll, degrees; frame poses after local BA) and the segment's end-to-end length against the truth (meaningful for the straight rows only).

    PYTHONPATH=$PWD python docs/results/s12_drift/segments.py RUN1.npz [RUN2.npz ...]
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from canopy.metrics import align_trajectory, ape  # noqa: E402
from diagnose_drift import rotvec  # noqa: E402
from canopy.frontend.geometry import se3_inv  # noqa: E402

SEGMENTS = ((0, 303, "row 1"), (303, 506, "turn 1"), (506, 810, "row 2"), (810, 1013, "turn 2"))


def summary(path: str) -> str:
    d = np.load(path)
    final, gt = d["final"], d["gt"]
    a = ape(final, gt, align="se3")["rmse"]
    err = align_trajectory(final, gt, with_scale=False)[:, :3, 3] - gt[:, :3, 3]
    rms = np.sqrt((err ** 2).mean(axis=0))
    out = [f"{Path(path).name}: ATE {a:.4f} m, x/y/z {rms[0]:.4f}/{rms[1]:.4f}/{rms[2]:.4f}, "
           f"kf {int(d['is_kf'].sum())}"]
    for s, e, name in SEGMENTS:
        e = min(e, len(final) - 1)
        de = se3_inv(final[s]) @ final[e]
        dg = se3_inv(gt[s]) @ gt[e]
        r = np.degrees(rotvec(dg[:3, :3].T @ de[:3, :3]))  # rotation error picked up from s to e
        le = np.linalg.norm(final[e, :3, 3] - final[s, :3, 3])
        lg = np.linalg.norm(gt[e, :3, 3] - gt[s, :3, 3])
        out.append(f"  {name:7s} {s:4d}-{e:4d}: pitch {r[0]:+.3f} yaw {r[1]:+.3f} roll {r[2]:+.3f} deg, "
                   f"length {100 * (le / lg - 1):+.2f} %")
    return "\n".join(out)


if __name__ == "__main__":
    if len(sys.argv) < 2:
        raise SystemExit(__doc__)
    for p in sys.argv[1:]:
        print(summary(p))
