"""The lines test's comparison (tests/test_lines_pipeline.py kitti_runs) with tracking overrides."""
import sys, numpy as np
from canopy.config import load_run_config, with_overrides
from canopy.pipeline import run_sequential
from canopy.sources import open_source
from canopy.metrics import ape
from dataclasses import replace
kw = {}
for a in sys.argv[1:]:
    k, v = a.split("=")
    kw[k] = v if k == "subpixel_normalise" else float(v)
src = open_source("kitti")
cfg = load_run_config("kitti")
cfg = replace(cfg, tracking=replace(cfg.tracking, **kw))
off = run_sequential(src, cfg.tracking, cfg.mapping)
cfg_on = with_overrides(cfg, lines=True)
on = run_sequential(src, cfg_on.tracking, cfg_on.mapping)
for n, r in (("points", off), ("lines", on)):
    e = ape(r.trajectory.poses, src.ground_truth.poses, align="se3")["rmse"]
    s = ape(r.trajectory.poses, src.ground_truth.poses, align="sim3")["rmse"] if True else 0
    print(n, kw, "ate_se3 %.4f sim3 %.4f lost %d" % (e, s, r.n_lost), flush=True)
