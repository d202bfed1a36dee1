"""Where a KITTI cell's ATE comes from (s24-kittinoisy), from diag_far.py's JSON (est / gt poses): the trajectory
rebuilt from its frame-to-frame motions with (a) the estimated rotations and the true translation steps, (b) the
true rotations and the estimated translation steps, and (c) per frame, the ATE with that one frame's motion
replaced by the true one (the frames whose error costs most).

    PYTHONPATH=$PWD python docs/results/s24_kittinoisy/decompose.py /tmp/kittinoisy-diag-base-s0.json [...]
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))
from canopy.metrics import ape, ate_sim3  # noqa: E402


def rel(P):
    return [np.linalg.inv(P[i - 1]) @ P[i] for i in range(1, len(P))]


def compose(start, steps):
    out = [start]
    for d in steps:
        out.append(out[-1] @ d)
    return np.array(out)


def mix(R_from, t_from):
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = R_from[:3, :3], t_from[:3, 3]
    return m


def ate(P, gt):
    return ape(P, gt, "se3")["rmse"] * 1000


def main():
    for f in sys.argv[1:]:
        d = json.loads(Path(f).read_text())
        est, gt = np.array(d["est"]), np.array(d["gt"])
        de, dg = rel(est), rel(gt)
        full = ate(compose(est[0], de), gt)
        rot_only = ate(compose(est[0], [mix(e, g) for e, g in zip(de, dg)]), gt)
        trans_only = ate(compose(est[0], [mix(g, e) for e, g in zip(de, dg)]), gt)
        # translation step error split: along the true step (scale) and across it
        along, across = [], []
        for e, g in zip(de, dg):
            tg, te = g[:3, 3], e[:3, 3]
            n = np.linalg.norm(tg)
            u = tg / n
            along.append(float((te - tg) @ u))
            across.append(float(np.linalg.norm((te - tg) - ((te - tg) @ u) * u)))
        gain = []
        for k in range(len(de)):
            steps = list(de)
            steps[k] = dg[k]
            gain.append(full - ate(compose(est[0], steps), gt))
        top = np.argsort(gain)[::-1][:6]
        print(f"{Path(f).stem}: ATE {full:.1f} mm (Sim3 {ate_sim3(est, gt)['rmse'] * 1000:.1f}); est rotations + true "
              f"translation steps {rot_only:.1f}; true rotations + est translation steps {trans_only:.1f}; "
              f"step error along rms {np.sqrt(np.mean(np.square(along))) * 1000:.1f} mm (mean {np.mean(along) * 1000:+.1f}), "
              f"across rms {np.sqrt(np.mean(np.square(across))) * 1000:.1f} mm")
        print("   frames whose true motion lowers the ATE most (frame: mm): "
              + ", ".join(f"{k + 1}: {gain[k]:.1f}" for k in top))


if __name__ == "__main__":
    main()
