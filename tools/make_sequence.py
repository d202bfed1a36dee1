"""Generate a synthetic orchard stereo sequence (EuRoC ASL layout, exact ground truth).

    python tools/make_sequence.py --preset dusk-loop --out data/synthetic/dusk-loop
    python tools/make_sequence.py --preset haze-row --haze-beta 0.2 --frames 300 --out /tmp/haze
    python tools/make_sequence.py --preset day-loop --camera kitti --length 60 --out /tmp/kitti-like

The folder it writes opens with ``open_source("euroc", <out>)``. Re-running
with the same arguments reuses the cached sequence.
"""
from __future__ import annotations

import os
import sys

# Run as a script, Python puts tools/ first on sys.path; the repository root is what
# must be importable (canopy, shared), so it takes that place.
sys.path[0] = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

import argparse  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

from canopy.synthetic import PRESETS, RIGS, generate_sequence  # noqa: E402
from canopy.synthetic.presets import PRESET_HELP  # noqa: E402
from shared.errors import CanopyError  # noqa: E402


def _parse(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="presets:\n" + "\n".join(f"  {k:10s} {v}" for k, v in PRESET_HELP.items()))
    ap.add_argument("--preset", required=True, help=f"one of: {', '.join(PRESETS)}")
    ap.add_argument("--out", required=True, type=Path, help="output folder (created; must be empty or a previous output)")
    n = ap.add_mutually_exclusive_group()
    n.add_argument("--frames", type=int, default=None, help="number of stereo frames (default: from the preset's length)")
    n.add_argument("--length", type=float, default=None, help="path length to drive in metres")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--camera", default=None, help=f"camera rig: {', '.join(RIGS)}")
    ap.add_argument("--haze-beta", type=float, default=None, help="haze density beta (1/m), >= 0")
    ap.add_argument("--light-start", type=float, default=None, help="light level at the start (1 = day)")
    ap.add_argument("--light-end", type=float, default=None, help="light level at the end")
    ap.add_argument("--speed", type=float, default=None, help="cruise speed (m/s)")
    ap.add_argument("--gain", type=float, default=None, help="sensor analogue gain")
    ap.add_argument("--no-noise", action="store_true", help="no shot/read noise (still 8-bit)")
    ap.add_argument("--low-texture", action="append", default=None, metavar="X0:X1",
                    help="world-x range (m) with washed-out texture; repeatable")
    ap.add_argument("--no-depth", action="store_true", help="do not write the depth0 folder")
    ap.add_argument("--workers", type=int, default=None, help="render processes (default: up to 2)")
    return ap.parse_args(argv)


def _overrides(a: argparse.Namespace) -> dict:
    o: dict = {}
    for key, value in (("camera", a.camera), ("haze_beta", a.haze_beta), ("light_start", a.light_start),
                       ("light_end", a.light_end), ("speed", a.speed), ("gain", a.gain), ("length_m", a.length)):
        if value is not None:
            o[key] = value
    if a.no_noise:
        o["noise"] = False
    if a.no_depth:
        o["write_depth"] = False
    if a.low_texture:
        zones = []
        for z in a.low_texture:
            try:
                x0, x1 = (float(v) for v in z.split(":"))
            except ValueError:
                raise SystemExit(f"make_sequence: --low-texture {z!r}: expected X0:X1 in metres") from None
            zones.append((x0, x1))
        o["low_texture"] = tuple(zones)
    return o


def main(argv: list[str] | None = None) -> int:
    a = _parse(argv)
    t0 = time.perf_counter()
    last = [0.0]

    def progress(done: int, total: int) -> None:
        now = time.perf_counter()
        if now - last[0] > 2.0 or done == total:
            last[0] = now
            rate = done / max(now - t0, 1e-9)
            print(f"  {done}/{total} frames  {rate:.1f} frames/s", flush=True)

    try:
        path = generate_sequence(a.preset, a.out, n_frames=a.frames, seed=a.seed, workers=a.workers,
                                 progress=progress, **_overrides(a))
    except CanopyError as exc:
        print(f"make_sequence: error: {exc}", file=sys.stderr)
        return 2
    print(f"{a.preset}: {path} ready in {time.perf_counter() - t0:.1f} s "
          f"(open with open_source('euroc', '{path}'))")
    return 0


if __name__ == "__main__":
    sys.exit(main())
