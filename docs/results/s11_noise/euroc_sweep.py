"""EuRoC snippet (95 frames) in process, no enhancement (auto leaves these cells untouched, s9-jitter):
ATE (SE(3)-aligned rmse), frame-diff rms and keyframes for the clean snippet and degraded cells.
usage: python docs/results/s11_noise/euroc_sweep.py [cells=a,b,...] [seed=1] [section.name=value ...]"""
import os, sys, warnings; warnings.simplefilter("ignore")
sys.path.insert(0, os.getcwd() + '/benchmarks'); sys.path.insert(0, os.getcwd())
import numpy as np
from diagnose_tracking import run
from canopy.metrics import ape, align_trajectory

CELLS = ["clean", "g1-b0-low", "g1-b0.06-low", "g1-b0-high", "g1-b0.06-high"]
args = sys.argv[1:]
cells, seed = CELLS, 0
for a in list(args):
    if a.startswith("cells="):
        cells = a[6:].split(","); args.remove(a)
    if a.startswith("seed="):  # another noise draw (tools/degrade_sequence.py --seed; the grid's --seed)
        seed = int(a[5:]); args.remove(a)
out = []
for c in cells:
    path = None if c == "clean" else f"/work/cache/degraded/euroc-all-{c}-seed{seed}"
    src, res = run("euroc", path, None, args)
    gt = src.ground_truth.poses[:res.n_frames]; est = res.trajectory.poses
    ate = ape(est, gt, align="se3")['rmse'] * 1e3
    al = align_trajectory(est, gt, with_scale=False); e = al[:, :3, 3] - gt[:, :3, 3]
    fd = np.sqrt((np.diff(e, axis=0) ** 2).sum(1).mean()) * 1e3
    line = f"{c:18s} ATE {ate:.3f} mm  frame-diff {fd:.3f}  kfs {list(res.keyframe_indices)}"
    print(line, flush=True); out.append(line)
print("SETS", args, "seed", seed)
