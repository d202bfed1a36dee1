"""s17-kittihaze: where an ATE comes from. From diag_frames.py's --out npz: SE(3) and Sim(3) ATE, the
scale, and counterfactuals: the trajectory re-chained with the k worst frame-to-frame motions (by rotation
error) replaced by ground truth's, and with all rotations / all translations of the relative motions replaced.
Usage: ate_parts.py NPZ"""
import json
import sys
import numpy as np
sys.path.insert(0, ".")
from canopy.frontend.geometry import se3_inv
from canopy.metrics import ape

z = np.load(sys.argv[1]); est, gt = z["est"], z["gt"]; rows = json.loads(str(z["rows"]))
def ate(e, mode="se3"):
    r = ape(e, gt[: len(e)], mode)
    return 1000 * r["rmse"], r.get("scale", 1.0)
def rel(P): return [se3_inv(P[i - 1]) @ P[i] for i in range(1, len(P))]
def chain(R):
    out = [gt[0].copy()]
    for T in R:
        out.append(out[-1] @ T)
    return np.array(out)
re, rg = rel(est), rel(gt)
print("SE3 %.1f mm  Sim3 %.1f mm scale %s" % (ate(est)[0], ate(est, "sim3")[0], ate(est, "sim3")[1]))
def rot_deg(R): return float(np.degrees(np.arccos(np.clip(0.5 * (np.trace(R) - 1), -1, 1))))
err = np.array([rot_deg((se3_inv(g) @ e)[:3, :3]) for e, g in zip(re, rg)])
order = np.argsort(-err)
for k in (1, 2, 3, 5, 10):
    R = list(re)
    for j in order[:k]:
        R[j] = rg[j]
    print("worst %2d frames (by rot err: %s) from gt: SE3 %.1f mm" % (k, " ".join(str(j + 1) for j in order[:k]), ate(chain(R))[0]))
Rrot = [np.block([[g[:3, :3], e[:3, 3:4]], [e[3:4]]]) for e, g in zip(re, rg)]
Rtr = [np.block([[e[:3, :3], g[:3, 3:4]], [e[3:4]]]) for e, g in zip(re, rg)]
print("all rotations from gt: SE3 %.1f mm; all translations from gt: SE3 %.1f mm" % (ate(chain(Rrot))[0], ate(chain(Rtr))[0]))
Rn = [np.block([[e[:3, :3], (e[:3, 3:4] / np.linalg.norm(e[:3, 3]) * np.linalg.norm(g[:3, 3]))], [e[3:4]]]) for e, g in zip(re, rg)]
print("translation lengths from gt (directions, rotations kept): SE3 %.1f mm" % ate(chain(Rn))[0])
print("path length est %.3f gt %.3f" % (sum(np.linalg.norm(t[:3, 3]) for t in re), sum(np.linalg.norm(t[:3, 3]) for t in rg)))
