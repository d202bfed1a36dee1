"""Render speed of the synthetic orchard generator.

    python benchmarks/bench_render.py [--frames 60] [--out results/bench_render.json]

Rows: single-process stereo rendering (render + conditions, no disk) for the
EuRoC-like and KITTI-like rigs, and end-to-end ``generate_sequence`` (render
+ PNG writing, the default worker pool) on the EuRoC-like rig. Prints a table
and writes JSON.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import sys
import tempfile
import time
from pathlib import Path

sys.path[0] = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

from canopy.synthetic import SequenceGenerator, generate_sequence, resolve_params  # noqa: E402


def bench_render(preset: str, frames: int, **overrides) -> dict:
    gen = SequenceGenerator(resolve_params(preset, n_frames=frames, **overrides), 0)
    gen.stereo(0)  # warm-up
    t = time.perf_counter()
    for i in range(frames):
        gen.stereo(i)
    dt = time.perf_counter() - t
    c = gen.calibration
    return {"case": f"render {preset} {overrides.get('camera', 'euroc')}", "size": f"{c.width}x{c.height}",
            "frames": frames, "seconds": dt, "stereo_fps": frames / dt}


def bench_generate(preset: str, frames: int) -> dict:
    tmp = Path(tempfile.mkdtemp(prefix="bench_render_"))
    try:
        t = time.perf_counter()
        generate_sequence(preset, tmp / "seq", n_frames=frames, seed=0)
        dt = time.perf_counter() - t
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return {"case": f"generate_sequence {preset} (render + PNG, default workers)", "size": "752x480",
            "frames": frames, "seconds": dt, "stereo_fps": frames / dt}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--out", type=Path, default=Path("results/bench_render.json"))
    a = ap.parse_args()
    rows = [
        bench_render("day-loop", a.frames),
        bench_render("haze-row", a.frames),
        bench_render("day-loop", a.frames // 2, camera="kitti"),
        bench_generate("dusk-loop", 4 * a.frames),
    ]
    print(f"{'case':62s} {'size':>9s} {'frames':>6s} {'s':>7s} {'stereo fps':>10s}")
    for r in rows:
        print(f"{r['case']:62s} {r['size']:>9s} {r['frames']:6d} {r['seconds']:7.2f} {r['stereo_fps']:10.1f}")
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps({"benchmark": "bench_render", "cpu_count": os.cpu_count(),
                                 "python": platform.python_version(), "rows": rows}, indent=2) + "\n")
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
