import sys, numpy as np
from dataclasses import replace
from canopy.config import load_run_config
from canopy.pipeline import run_sequential
from canopy.sources import open_source
from canopy.metrics import ape
kw = {}
for a in sys.argv[1:]:
    k, v = a.split("="); kw[k] = v if k == "subpixel_normalise" else float(v)
src = open_source("kitti"); cfg = load_run_config("kitti")
r = run_sequential(src, replace(cfg.tracking, **kw), cfg.mapping)
est = np.array([T[:3, 3] for T in r.trajectory.poses]); gt = np.array([T[:3, 3] for T in src.ground_truth.poses])
L = lambda p: np.linalg.norm(np.diff(p, axis=0), axis=1).sum()
print(kw, "se3 %.4f sim3 %.4f path %.3f gt %.3f ratio %.4f" % (ape(r.trajectory.poses, src.ground_truth.poses, align="se3")["rmse"],
      ape(r.trajectory.poses, src.ground_truth.poses, align="sim3")["rmse"], L(est), L(gt), L(est) / L(gt)))
