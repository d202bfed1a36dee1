"""Speed of the loop closer's SE(3) pose-graph optimisation (issue 10: 1000 keyframes <= 1 s).

Graphs like the ones a loop produces: keyframes on a closed path (a 5-row orchard
serpentine, 1.6 m/s, a keyframe every ~0.3 m), odometry edges drifted by a constant bias
plus small noise, covisibility edges to the 2nd and 3rd next keyframe, and one loop edge
from the last keyframe to the first. Per size: wall time of ``optimise_pose_graph``
(median of runs, after one warm-up), LM iterations, and the worst position error against
the exact poses before / after.

    python benchmarks/bench_pose_graph.py [--sizes 250 500 1000 2000] [--runs 5] [--out docs/results/bench_pose_graph.json]
"""
from __future__ import annotations

import argparse
import platform
import statistics
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from canopy.frontend.geometry import se3_exp  # noqa: E402
from canopy.loop import COVISIBILITY, LOOP, ODOMETRY, LoopParams, PoseGraphEdge, optimise_pose_graph  # noqa: E402
from canopy.loop.pose_graph import relative  # noqa: E402
from canopy.report import write_json  # noqa: E402


def closed_path(n: int) -> dict[int, np.ndarray]:
    """n poses around a rounded rectangle (20 m x 16 m), camera looking along the path."""
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    x, z = 10 * np.cos(t), 8 * np.sin(t)
    heading = np.arctan2(np.gradient(z), np.gradient(x))
    poses = {}
    for k in range(n):
        T = se3_exp(np.array([0, 0, 0, 0, -heading[k] + np.pi / 2, 0]))
        T[:3, 3] = [x[k], 0.0, z[k]]
        poses[k] = T
    return poses


def make_graph(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    gt = closed_path(n)
    bias = se3_exp(np.array([0.0, 0.0, 0.001, 2e-4, 0.0, 0.0]))
    edges, est = [], {0: gt[0]}
    for k in range(1, n):
        odo = relative(gt[k - 1], gt[k]) @ bias @ se3_exp(rng.normal(0, 1e-4, 6))
        est[k] = est[k - 1] @ odo
        edges.append(PoseGraphEdge(k - 1, k, odo, ODOMETRY))
    for k in range(n):
        for d in (2, 3):
            if k + d < n:
                edges.append(PoseGraphEdge(k, k + d, relative(est[k], est[k + d]), COVISIBILITY))
    edges.append(PoseGraphEdge(0, n - 1, relative(gt[0], gt[n - 1]), LOOP))
    return gt, est, edges


def bench(n: int, runs: int) -> dict:
    gt, est, edges = make_graph(n)
    params = LoopParams()
    optimise_pose_graph(est, edges, params)  # warm-up
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        res = optimise_pose_graph(est, edges, params)
        times.append(time.perf_counter() - t0)
    err = lambda P: max(float(np.linalg.norm(P[k][:3, 3] - gt[k][:3, 3])) for k in gt)  # noqa: E731
    return {"keyframes": n, "edges": len(edges), "median_s": statistics.median(times), "max_s": max(times),
            "iterations": res.iterations, "max_error_before_m": err(est), "max_error_after_m": err(res.poses)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[250, 500, 1000, 2000])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--out", default=str(ROOT / "docs" / "results" / "bench_pose_graph.json"))
    args = ap.parse_args()
    rows = [bench(n, args.runs) for n in args.sizes]
    head = ["keyframes", "edges", "median_s", "max_s", "iterations", "max_error_before_m", "max_error_after_m"]
    print(" | ".join(f"{h:>18}" for h in head))
    for r in rows:
        print(" | ".join(f"{r[h]:>18.4f}" if isinstance(r[h], float) else f"{r[h]!s:>18}" for h in head))
    out = write_json(args.out, {"benchmark": "pose_graph", "date": datetime.now(timezone.utc).isoformat(),
                                "machine": {"platform": platform.platform(), "python": platform.python_version()},
                                "note": "timings on a shared, loaded 2-core machine: indicative only", "rows": rows})
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
