"""Check how well a stereo rig's pairs are rectified: the right image's row offset over the image, from the
images alone (canopy.frontend.row_alignment).

Stereo matching searches one row, so a rig whose rows are off by more than a fraction of a pixel matches
patches that are off vertically, and its disparities pay for it. This tracks nothing. Per frame it takes the
tracker's own stereo matches (the config's extractor and matcher, level-0 keypoints), measures each right
patch's sub-pixel row offset, and fits v_r − v_l = offset + roll·(u − cx) + row_scale·(v − cy) over all the
frames (standard errors by a jackknife over frames). It prints that fit, the offset at the four corners, and a verdict against ``--warn-px``. Exit code 0
when within, 1 when not, 2 on bad input.

    python tools/check_rectification.py --dataset kitti                      # the bundled KITTI 06 snippet
    python tools/check_rectification.py --dataset folder --path my_rig/ --frames 50 --out rows.json
"""
from __future__ import annotations

import os
import sys

sys.path[0] = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

import argparse  # noqa: E402
import json  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from canopy.config import load_run_config  # noqa: E402
from canopy.frontend.cell_extractor import make_extractor  # noqa: E402
from canopy.frontend.row_alignment import RowMisalignment, fit_row_misalignment, patch_row_offsets  # noqa: E402
from canopy.frontend.stereo import match_stereo  # noqa: E402
from canopy.sources import open_source  # noqa: E402
from shared.errors import CanopyError, InputError  # noqa: E402

CORNERS = ("top-left", "top-right", "bottom-left", "bottom-right")


def measure_rows(src, tracking, frames: int, step: int = 1) -> RowMisalignment:
    """The fitted row misalignment over every ``step``-th of the first ``frames`` frames of ``src``."""
    c = src.calibration
    ex_l, ex_r = make_extractor(tracking), make_extractor(tracking)
    us, vs, offs, frames_of = [], [], [], []
    for i in range(0, min(frames, len(src)), max(1, step)):
        f = src.frame(i)
        left, right = ex_l.extract(f.left), ex_r.extract(f.right)
        st = match_stereo(left, right, f.left, f.right, c, tracking)
        sel = np.flatnonzero(st.valid & (left.octave == 0))   # level-0 keypoints: whole-pixel windows
        idx, off = patch_row_offsets(f.left, f.right, left.uv[sel, 0], left.uv[sel, 1], st.u_right[sel],
                                     tracking.subpixel_window)
        us.append(left.uv[sel[idx], 0])
        vs.append(left.uv[sel[idx], 1])
        offs.append(off)
        frames_of.append(np.full(len(off), i))
    n = int(sum(len(o) for o in offs))
    if n < 10:
        raise InputError(getattr(src, "root", "dataset"), f"only {n} stereo matches could be measured; "
                         "is this a rectified stereo pair with texture?")
    return fit_row_misalignment(np.concatenate(us), np.concatenate(vs), np.concatenate(offs), c.cx, c.cy,
                                c.width, c.height, groups=np.concatenate(frames_of))


def report(fit: RowMisalignment, warn_px: float) -> str:
    lines = [f"row offset of the right image (v_r - v_l), {fit.n_matches} matches, "
             f"residual {fit.residual_px:.3f} px:",
             f"  constant  {fit.offset_px:+.3f} px   (se {fit.offset_se:.3f})",
             f"  roll      {np.degrees(fit.roll_rad):+.4f} deg ({fit.roll_rad:+.2e} rad per px of column, "
             f"se {fit.roll_se:.1e})",
             f"  row scale {100 * fit.row_scale:+.3f} %   (per px of row, se {100 * fit.row_scale_se:.3f} %)",
             "  at the corners: " + ", ".join(f"{n} {v:+.2f} px" for n, v in zip(CORNERS, fit.corners_px))]
    worst = CORNERS[int(np.argmax(np.abs(fit.corners_px)))]
    if fit.worst_corner_px <= warn_px:
        lines.append(f"rows aligned within {fit.worst_corner_px:.2f} px everywhere (limit {warn_px} px)")
    else:
        lines.append(f"WARNING: rows off by up to {fit.worst_corner_px:.2f} px ({worst} corner), over the "
                     f"{warn_px} px limit: stereo matching searches one row, re-rectify the rig")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--dataset", default="kitti", help="euroc | kitti | folder")
    ap.add_argument("--path", default=None, help="the dataset folder (default: the bundled copy)")
    ap.add_argument("--config", default=None, help="parameter file (default: configs/<dataset>.yaml)")
    ap.add_argument("--frames", type=int, default=100, help="use at most this many frames")
    ap.add_argument("--step", type=int, default=1, help="every step-th frame")
    ap.add_argument("--warn-px", type=float, default=0.5, help="largest acceptable row offset at a corner")
    ap.add_argument("--out", default=None, help="write the fit as JSON here")
    args = ap.parse_args(argv)
    try:
        if args.frames < 1 or args.step < 1:
            raise InputError("--frames/--step", f"must be >= 1 (got {args.frames}, {args.step})")
        cfg = load_run_config(args.dataset, args.config)
        src = open_source(args.dataset, args.path, max_frames=args.frames)
        fit = measure_rows(src, cfg.tracking, args.frames, args.step)
    except CanopyError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(report(fit, args.warn_px))
    if args.out:
        Path(args.out).write_text(json.dumps({"dataset": args.dataset, "path": args.path, **fit.as_dict()}, indent=1))
    return 0 if fit.worst_corner_px <= args.warn_px else 1


if __name__ == "__main__":
    sys.exit(main())
