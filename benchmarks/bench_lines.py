"""Speed and yield of line features on real stereo frames.

Per detector (FLD, LSD): ms per frame for detection, LBD description and stereo line
matching (median over frames x runs, after a warm-up), and the number of kept segments
and stereo line matches per frame. Frames: the first ``--frames`` pairs of the EuRoC
V1_01 micro slice (752x480) and the KITTI 06 snippet (1226x370).

    python benchmarks/bench_lines.py [--frames 10] [--runs 5] [--out results/bench_lines.json]
"""
from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from canopy.lines import LineDescriber, LineParams, detect_segments, match_stereo_lines  # noqa: E402
from canopy.sources import open_source  # noqa: E402

DATASETS = ("euroc", "kitti")
DETECTORS = ("fld", "lsd")
WARMUP = 2


def _ms(fn, runs):
    times, out = [], None
    for _ in range(runs):
        t = time.perf_counter()
        out = fn()
        times.append((time.perf_counter() - t) * 1e3)
    return out, times


def bench(kind: str, detector: str, n_frames: int, runs: int) -> dict:
    src = open_source(kind, max_frames=n_frames)
    calib = src.calibration
    params = LineParams(detector=detector)
    describe = LineDescriber(params)
    frames = [src.frame(i) for i in range(min(n_frames, len(src.timestamps)))]
    for f in frames[:1]:  # warm-up (OpenCV allocations, first-call costs)
        for _ in range(WARMUP):
            s, _ = detect_segments(f.left, params)
            describe(f.left, s)
    t_det, t_desc, t_match, n_seg, n_match, n_horiz, n_rej = [], [], [], [], [], [], []
    for f in frames:
        (sl, st), t = _ms(lambda: detect_segments(f.left, params), runs)
        t_det += t
        sr, _ = detect_segments(f.right, params)
        dl, t = _ms(lambda: describe(f.left, sl), runs)
        t_desc += t
        dr = describe(f.right, sr)
        m, t = _ms(lambda: match_stereo_lines(sl, dl, sr, dr, calib, params), runs)
        t_match += t
        n_seg.append(len(sl))
        n_match.append(len(m))
        n_horiz.append(m.stats["horizontal"])
        n_rej.append(st["nan"] + st["zero_length"] + st["outside"])
    med = statistics.median
    return {
        "dataset": kind, "detector": detector, "image": f"{calib.width}x{calib.height}", "frames": len(frames),
        "detect_ms": med(t_det), "describe_ms": med(t_desc), "match_ms": med(t_match),
        "total_left_ms": med(t_det) + med(t_desc) + med(t_match),
        "segments": med(n_seg), "stereo_matches": med(n_match), "horizontal_rejected": med(n_horiz),
        "degenerate_rejected": int(sum(n_rej)),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--out", default=str(ROOT / "results" / "bench_lines.json"))
    args = ap.parse_args()
    rows = [bench(k, d, args.frames, args.runs) for k in DATASETS for d in DETECTORS]
    head = ("dataset", "detector", "image", "detect_ms", "describe_ms", "match_ms", "total_left_ms",
            "segments", "stereo_matches", "horizontal_rejected", "degenerate_rejected")
    print(" | ".join(f"{h:>14}" for h in head))
    for r in rows:
        print(" | ".join(f"{r[h]:>14.2f}" if isinstance(r[h], float) else f"{r[h]!s:>14}" for h in head))
    result = {
        "benchmark": "bench_lines", "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "machine": {"python": platform.python_version(), "opencv": cv2.__version__, "numpy": np.__version__,
                    "cpu": platform.processor() or platform.machine(), "threads": cv2.getNumThreads()},
        "params": {d: LineParams(detector=d).__dict__ for d in DETECTORS},
        "note": "ms per frame for the left image (the right image costs the same for detection/description); "
                "median over frames x runs after warm-up",
        "rows": rows,
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
