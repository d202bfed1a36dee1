"""Monocular loop closing in Sim(3): the same monocular run with and without the loop closer.

Runs the in-process lockstep monocular pipeline (``canopy.mono.pipeline.run_mono_sequential``)
on each sequence twice: loops off, then loops on (shipped vocabulary, ``MonoLoopCloser``, and
relocalisation of lost frames by keyframe-database query + PnP). Sequences: generated presets
(``--presets``) and, with ``--kitti-gap A-B``, the KITTI 06 snippet with frames A..B black (a
covered camera: the tracker loses everything and must find the map again).
Reported per run: Sim(3) ATE RMSE over tracked frames with its scale, the scale fitted on
the first and on the last ``--window`` tracked frames (scale drift), tracked %, keyframes,
loops closed (query -> candidate, inliers, loop scale), wall time (noisy on a shared
machine: for orientation only). JSON in ``docs/results/bench_mono_loops.json``.

    CANOPY_CACHE_DIR=/work/cache python benchmarks/bench_mono_loops.py [--presets day-loop] [--max-frames N]
    python benchmarks/bench_mono_loops.py --presets --kitti-gap 20-24
"""
from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from canopy.config import load_run_config  # noqa: E402
from canopy.loop.vocabulary import load_vocabulary  # noqa: E402
from canopy.metrics import associate, ate_sim3  # noqa: E402
from canopy.mono import MonoParams  # noqa: E402
from canopy.mono.pipeline import run_mono_sequential  # noqa: E402
from canopy.report import write_json  # noqa: E402
from canopy.sources import open_source  # noqa: E402
from shared.types import StereoFrame  # noqa: E402


class BlankedSource:
    """``source`` with the frames in ``blank`` black in both images (as tools/make_gap_sequence.py)."""

    def __init__(self, source, blank: set[int]):
        self.source, self.blank = source, blank
        self.calibration, self.timestamps = source.calibration, source.timestamps
        self.ground_truth = source.ground_truth

    def __len__(self) -> int:
        return len(self.source)

    def frame(self, i: int) -> StereoFrame:
        f = self.source.frame(i)
        if i not in self.blank:
            return f
        return StereoFrame(f.index, f.timestamp, np.zeros_like(f.left), np.zeros_like(f.right))


def evaluate(res, gt, window: int) -> dict:
    traj = res.trajectory
    ia, ib = associate(traj.stamps, gt.stamps, 0.01)
    ok = res.tracked_mask[ia]
    ia, ib = ia[ok], ib[ok]
    out = {"tracked_percent": 100.0 * float(res.tracked_mask.mean()), "keyframes": len(res.keyframe_indices),
           "first_initialised": res.first_initialised, "n_initialisations": res.n_initialisations,
           "n_relocalised": res.n_relocalised,
           "loops": [{"query": int(c.constraint.query), "candidate": int(c.constraint.candidate),
                      "inliers": int(c.constraint.n_inliers), "scale": float(getattr(c.constraint, "scale", 1.0))}
                     for c in res.closures], "detection": res.detection}
    if len(ia) >= 3:
        a = ate_sim3(traj.poses[ia], gt.poses[ib])
        out.update(ate_sim3_m=a["rmse"], scale=a["scale"], n=a["n"])
        w = min(window, len(ia) // 2)
        out["scale_first_window"] = ate_sim3(traj.poses[ia[:w]], gt.poses[ib[:w]])["scale"]
        out["scale_last_window"] = ate_sim3(traj.poses[ia[-w:]], gt.poses[ib[-w:]])["scale"]
        P = gt.positions[ib]
        out["path_m"] = float(np.linalg.norm(np.diff(P, axis=0), axis=1).sum())
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presets", nargs="*", default=["day-loop"])
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--window", type=int, default=100, help="frames of the first/last scale fit")
    ap.add_argument("--modes", nargs="*", default=["off", "on"], choices=["off", "on"])
    ap.add_argument("--kitti-gap", default=None, help="also KITTI 06 with these frames black, e.g. 20-24")
    ap.add_argument("--out", default=str(ROOT / "docs" / "results" / "bench_mono_loops.json"))
    args = ap.parse_args(argv)
    from canopy.app import prepare_synthetic

    vocabulary = load_vocabulary()
    rows = []
    runs = [(p, lambda p=p: open_source("euroc", prepare_synthetic(p, None, 0, False), max_frames=args.max_frames),
             "euroc") for p in args.presets]
    if args.kitti_gap:
        a, b = (int(x) for x in args.kitti_gap.split("-"))
        runs.append((f"kitti06 frames {a}-{b} black", lambda: BlankedSource(open_source("kitti"), set(range(a, b + 1))),
                     "kitti"))
    for preset, opener, kind in runs:
        src = opener()
        tracking = load_run_config(kind).tracking
        for mode in args.modes:
            t0 = time.perf_counter()
            res = run_mono_sequential(src, tracking, MonoParams(), vocabulary=vocabulary if mode == "on" else None)
            row = {"sequence": preset, "frames": len(src), "loops_mode": mode,
                   "wall_s": time.perf_counter() - t0, **evaluate(res, src.ground_truth, args.window)}
            rows.append(row)
            print(f"{preset:10s} loops {mode:3s}  ATE(Sim3) {row.get('ate_sim3_m', float('nan')):.3f} m  "
                  f"scale {row.get('scale', float('nan')):.3f} (first {row.get('scale_first_window', float('nan')):.3f}, "
                  f"last {row.get('scale_last_window', float('nan')):.3f})  tracked {row['tracked_percent']:.1f} %  "
                  f"kf {row['keyframes']}  loops {len(row['loops'])}  inits {row['n_initialisations']}  "
                  f"relocalised {row['n_relocalised']}  {row['wall_s']:.0f} s", flush=True)
    write_json(args.out, {"created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
                          "machine": {"cpus": os.cpu_count(), "platform": platform.platform(),
                                      "load_avg": os.getloadavg()},
                          "note": "wall times on a shared machine: orientation only", "rows": rows})
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
