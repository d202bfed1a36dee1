"""Make a copy of a KITTI-layout stereo sequence with some frames blanked in both cameras.

A blank (black) stretch is what a camera gives when it is covered, saturated or in full
darkness: tracking loses every feature and must find the map again afterwards (issue 10:
"KITTI 06 with frames 20-24 blank in both cameras"). Everything else (calibration, times,
ground-truth poses, the other images) is copied unchanged.

With ``--resume-at N`` the camera is also "kidnapped": after the last blank frame the copy
shows the source from frame N on (images and ground-truth poses; times stay as they are), a
place seen earlier that the motion model cannot predict, only a relocalisation by database
query can find.

    python tools/make_gap_sequence.py OUT [--src data/kitti06_snippet] [--blank 20-24] [--resume-at N]
"""
from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from canopy.sources.kitti import IMAGE_DIR_PAIRS  # noqa: E402
from shared.errors import CanopyError, InputError  # noqa: E402


def parse_range(text: str) -> list[int]:
    """'20-24' or '20,21,30-32' -> sorted frame indices."""
    out: set[int] = set()
    try:
        for part in text.split(","):
            a, _, b = part.strip().partition("-")
            out.update(range(int(a), int(b or a) + 1))
    except ValueError:
        raise InputError("--blank", f"expected frame ranges like 20-24 or 3,7-9, got {text!r}") from None
    return sorted(out)


def make_gap_sequence(src: Path, out: Path, blank: list[int], resume_at: int | None = None) -> Path:
    src, out = Path(src), Path(out)
    pair = next(((a, b) for a, b in IMAGE_DIR_PAIRS if (src / a).is_dir() and (src / b).is_dir()), None)
    if pair is None:
        raise InputError(src, f"not a KITTI-layout folder (needs one of {IMAGE_DIR_PAIRS})")
    if out.resolve() == src.resolve():
        raise InputError(out, "output folder is the source folder")
    if out.exists():
        shutil.rmtree(out)
    shutil.copytree(src, out)
    for cam in pair:
        files = sorted(p for p in (out / cam).iterdir() if p.suffix.lower() in (".png", ".jpg", ".jpeg"))
        for i in blank:
            if i >= len(files):
                raise InputError(src / cam, f"frame {i} to blank does not exist ({len(files)} frames)")
            img = cv2.imread(str(files[i]), cv2.IMREAD_UNCHANGED)
            cv2.imwrite(str(files[i]), np.zeros_like(img))
        if resume_at is not None:
            _resume(src / cam, files, blank, resume_at)
    if resume_at is not None:
        gt = out / "poses.txt"
        if gt.is_file():
            rows = gt.read_text().splitlines()
            after = range(max(blank) + 1, len(rows))
            rows[max(blank) + 1:] = [rows[resume_at + j] for j in range(len(after))]
            gt.write_text("\n".join(rows) + "\n")
    resumed = "" if resume_at is None else f"; after them the source from frame {resume_at} on (kidnapped camera)"
    (out / "GAP.md").write_text(f"Copy of {src} with frames {blank} blanked (black) in both cameras{resumed} "
                                f"by tools/make_gap_sequence.py.\n")
    return out


def _resume(src_cam: Path, files: list[Path], blank: list[int], resume_at: int) -> None:
    """Frames after the gap show the source from ``resume_at`` on (an earlier place: every frame has a source)."""
    if not blank:
        raise InputError("--resume-at", "needs frames to blank (the camera is carried away in the dark)")
    if not 0 <= resume_at <= max(blank):
        raise InputError("--resume-at", f"must be a frame before the end of the gap (0..{max(blank)}), got {resume_at}")
    src_files = sorted(p for p in src_cam.iterdir() if p.suffix.lower() in (".png", ".jpg", ".jpeg"))
    for j, i in enumerate(range(max(blank) + 1, len(files))):
        shutil.copyfile(src_files[resume_at + j], files[i])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("out", help="output folder (replaced if it exists)")
    ap.add_argument("--src", default=str(ROOT / "data" / "kitti06_snippet"))
    ap.add_argument("--blank", default="20-24", help="frames to blank, e.g. 20-24 or 3,7-9")
    ap.add_argument("--resume-at", type=int, default=None, metavar="N",
                    help="after the blank frames, continue with the source's frame N (a kidnapped camera)")
    args = ap.parse_args(argv)
    try:
        out = make_gap_sequence(Path(args.src), Path(args.out), parse_range(args.blank), args.resume_at)
    except CanopyError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
