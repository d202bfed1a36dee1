#!/usr/bin/env python
"""In-process lockstep run (tracking + local mapping, as ``diagnose_tracking.py``) that reports
what cross-keyframe triangulation (mapping.triangulate_new_points, canopy.backend.triangulation)
did: ATE, keyframes, landmarks made / alive / observation counts, how many triangulated
landmarks tracking matched per keyframe, and the local mapper's thread CPU per keyframe (whole
insert and the triangulation step, ``time.thread_time``: load-robust).

    PYTHONPATH=$PWD python benchmarks/diagnose_triangulation.py --dataset kitti --set mapping.triangulate_new_points=true
    PYTHONPATH=$PWD python benchmarks/diagnose_triangulation.py --dataset kitti \
        --path $CANOPY_CACHE_DIR/degraded/kitti-all-g1-b0.06-high-seed1 --set mapping.triangulate_new_points=true
    PYTHONPATH=$PWD python benchmarks/diagnose_triangulation.py --dataset synthetic \
        --path $CANOPY_CACHE_DIR/synthetic/day-loop-seed0-full --set mapping.triangulate_new_points=true

A degraded cell's folder runs without enhancement (right for the g1 cells, whose auto
enhancement decides "none"; the darker cells need bench_degrade_grid.py).
"""
from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from canopy.backend.local_mapper import LocalMapper  # noqa: E402
from canopy.config import load_run_config, parse_setting, with_settings  # noqa: E402
from canopy.metrics import ape  # noqa: E402
from canopy.pipeline import run_sequential  # noqa: E402
from canopy.sources import open_source  # noqa: E402


class _Probe:
    """Wraps the mapper's per-keyframe step to time it and count triangulated matches."""

    def __init__(self):
        self.mapper = None
        self.cpu_ms: list[float] = []
        self.tri_cpu_ms: list[float] = []
        self.matched: list[int] = []
        self._insert = LocalMapper.insert_keyframe
        self._tri = LocalMapper._triangulate_new_points
        self._init = LocalMapper.__init__
        probe = self

        def init(mapper, *a, **k):
            probe._init(mapper, *a, **k)
            probe.mapper = mapper

        def insert(mapper, kf):
            probe.matched.append(int((np.asarray(kf.landmark_ids) >= mapper.params.triangulate_id_base).sum()))
            t = time.thread_time()
            out = probe._insert(mapper, kf)
            probe.cpu_ms.append((time.thread_time() - t) * 1e3)
            return out

        def tri(mapper, rec, scale):
            t = time.thread_time()
            probe._tri(mapper, rec, scale)
            probe.tri_cpu_ms.append((time.thread_time() - t) * 1e3)

        LocalMapper.__init__, LocalMapper.insert_keyframe, LocalMapper._triangulate_new_points = init, insert, tri


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dataset", default="kitti", choices=["kitti", "euroc", "synthetic"])
    ap.add_argument("--path", default=None)
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--set", action="append", default=[], help="section.name=value parameter override")
    args = ap.parse_args()
    cfg = with_settings(load_run_config(args.dataset), [parse_setting(s) for s in args.set])
    src = open_source("euroc" if args.dataset == "synthetic" else args.dataset, args.path, max_frames=args.max_frames)
    probe = _Probe()
    res = run_sequential(src, cfg.tracking, cfg.mapping, map_update_lag=cfg.runtime.map_update_lag_frames)
    gt = src.ground_truth.poses[: res.n_frames]
    a = ape(res.trajectory.poses, gt, align="se3")
    pl_e = res.trajectory.path_length()
    pl_g = float(np.sum(np.linalg.norm(np.diff(gt[:, :3, 3], axis=0), axis=1)))
    m = probe.mapper
    base = m.params.triangulate_id_base
    tri = [lm for lid, lm in m.landmarks.items() if lid >= base]
    print(f"ATE {a['rmse']:.4f} m  path {pl_e:.3f}/{pl_g:.3f} m ({100 * (pl_e / pl_g - 1):+.2f} %)  "
          f"keyframes {len(m.keyframes)}  lost {res.n_lost}  landmarks {len(m.landmarks)}")
    print(f"triangulated: made {m.n_triangulated}, alive {len(tri)}, observations "
          f"{dict(sorted(Counter(min(len(lm.obs), 6) for lm in tri).items()))} (6 = 6+); "
          f"matched by tracking per keyframe {np.mean(probe.matched):.1f}")
    if tri:
        d = [np.linalg.norm(lm.position - m.keyframes[min(lm.obs)].T_world_cam[:3, 3]) for lm in tri]
        print("alive triangulated landmarks' distance from their first keyframe p10/50/90 (m):",
              np.percentile(d, [10, 50, 90]).round(1).tolist())
    tri_ms = np.mean(probe.tri_cpu_ms) if probe.tri_cpu_ms else 0.0
    print(f"local mapper thread CPU per keyframe: {np.mean(probe.cpu_ms):.1f} ms (triangulation {tri_ms:.1f} ms)")


if __name__ == "__main__":
    main()
