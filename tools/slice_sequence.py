"""Make a view of frames [start, stop) of a EuRoC-layout stereo sequence (generated orchards too).

For maps that outlive a run (issue 10): map the first part of a sequence, save the map, then
run a later part with ``--load-map``. The view lists only the chosen frames in each camera's
``data.csv``; images are symlinked, not copied; calibration, ground truth and the generator's
``params.json`` are copied unchanged, so the later part keeps its original times and poses
(the ATE of the second run is measured in the same frame as the first).

    python tools/slice_sequence.py SRC OUT --start 40 [--stop 120]
"""
from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from shared.errors import CanopyError, InputError  # noqa: E402

CAMERAS = ("cam0", "cam1", "depth0")


def slice_sequence(src: Path, out: Path, start: int, stop: int | None = None) -> Path:
    src, out = Path(src), Path(out)
    mav0 = src / "mav0"
    if not (mav0 / "cam0" / "data.csv").is_file():
        raise InputError(src, "not a EuRoC-layout folder (no mav0/cam0/data.csv)")
    if out.resolve() == src.resolve():
        raise InputError(out, "output folder is the source folder")
    if start < 0 or (stop is not None and stop <= start):
        raise InputError("--start/--stop", f"need 0 <= start < stop, got {start}, {stop}")
    if out.exists():
        shutil.rmtree(out)
    (out / "mav0").mkdir(parents=True)
    for f in src.iterdir():
        if f.is_file():
            shutil.copy2(f, out / f.name)
    for d in mav0.iterdir():
        if d.name in CAMERAS and (d / "data.csv").is_file():
            (out / "mav0" / d.name).mkdir()
            for f in d.iterdir():
                if f.is_dir():
                    (out / "mav0" / d.name / f.name).symlink_to(f.resolve(), target_is_directory=True)
                elif f.name != "data.csv":
                    shutil.copy2(f, out / "mav0" / d.name / f.name)
            lines = (d / "data.csv").read_text().splitlines()
            header = [ln for ln in lines if ln.startswith("#")]
            rows = [ln for ln in lines if ln.strip() and not ln.startswith("#")]
            if start >= len(rows):
                raise InputError(d / "data.csv", f"start frame {start} is past the last frame ({len(rows)} frames)")
            (out / "mav0" / d.name / "data.csv").write_text("\n".join(header + rows[start:stop]) + "\n")
        elif d.is_dir():
            shutil.copytree(d, out / "mav0" / d.name, symlinks=True)
        else:
            shutil.copy2(d, out / "mav0" / d.name)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("src")
    ap.add_argument("out")
    ap.add_argument("--start", type=int, required=True, help="first frame of the view (0-based)")
    ap.add_argument("--stop", type=int, default=None, help="one past the last frame (default: the end)")
    args = ap.parse_args(argv)
    try:
        out = slice_sequence(Path(args.src), Path(args.out), args.start, args.stop)
    except CanopyError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
