"""Row alignment of a rectified pair (canopy.frontend.row_alignment, tools/check_rectification.py): a known
row field put into a real KITTI pair is measured back; the fit recovers exact coefficients through outliers;
bad input is refused by name."""
from __future__ import annotations

import dataclasses
import json

import cv2
import numpy as np
import pytest

from canopy.config import load_run_config
from canopy.frontend.cell_extractor import make_extractor
from canopy.frontend.row_alignment import fit_row_misalignment, patch_row_offsets
from canopy.frontend.stereo import match_stereo
from canopy.sources import open_source
from tools.check_rectification import main as check_main
from tools.check_rectification import measure_rows

FRAMES = 8


class _ShiftedRight:
    """A source whose right images are resampled so that their rows move down by a + b (u - cx) + c (v - cy)."""

    def __init__(self, src, a, b, c):
        self.src, self.calibration = src, src.calibration
        self.field = (a, b, c)

    def __len__(self):
        return len(self.src)

    def frame(self, i):
        f = self.src.frame(i)
        h, w = f.right.shape
        cal = self.calibration
        u, v = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
        a, b, c = self.field
        shift = a + b * (u - cal.cx) + c * (v - cal.cy)
        # R'(u, v) = R(u, v - shift): what the right camera saw at row v_r now appears at v_r + shift (bicubic: a
        # bilinear resampling blurs the shifted image and under-reads a 0.2 px shift by 0.04)
        right = cv2.remap(f.right, u, v - shift, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)
        return dataclasses.replace(f, right=right)


@pytest.fixture(scope="module")
def kitti():
    return open_source("kitti", None, max_frames=FRAMES), load_run_config("kitti").tracking


def _offsets(src, pair_src, tracking):
    """Row offsets measured on ``pair_src``'s images at the stereo matches ``src``'s own pairs give (the same
    matches for both pairs), with each match's frame."""
    ex_l, ex_r = make_extractor(tracking), make_extractor(tracking)
    u, v, off, frame = [], [], [], []
    for i in range(len(src)):
        f, g = src.frame(i), pair_src.frame(i)
        left, right = ex_l.extract(f.left), ex_r.extract(f.right)
        st = match_stereo(left, right, f.left, f.right, src.calibration, tracking)
        sel = np.flatnonzero(st.valid & (left.octave == 0))
        idx, o = patch_row_offsets(g.left, g.right, left.uv[sel, 0], left.uv[sel, 1], st.u_right[sel])
        u.append(left.uv[sel[idx], 0])
        v.append(left.uv[sel[idx], 1])
        off.append(o)
        frame.append(np.full(len(o), i))
    return tuple(np.concatenate(x) for x in (u, v, off, frame))


def test_a_row_field_put_into_a_real_pair_is_measured_back(kitti):
    src, tracking = kitti
    c = src.calibration
    a, b, k = 0.4, 3.0e-4, -5.0e-4
    fits = []
    for pair in (src, _ShiftedRight(src, a, b, k)):
        u, v, off, frame = _offsets(src, pair, tracking)
        fits.append(fit_row_misalignment(u, v, off, c.cx, c.cy, c.width, c.height, groups=frame))
    base, moved = fits
    assert moved.offset_px - base.offset_px == pytest.approx(a, abs=0.05)
    assert moved.roll_rad - base.roll_rad == pytest.approx(b, abs=4e-5)
    assert moved.row_scale - base.row_scale == pytest.approx(k, abs=2.5e-4)   # rows span less than columns


def test_kitti_rows_turn_across_the_image(kitti):
    """The bundled KITTI pair's own misalignment, through the tool's path: a roll far outside its jackknife
    error (docs/notes/s32-oracle.md §7) and up to ~0.5 px at the corners."""
    src, tracking = kitti
    fit = measure_rows(src, tracking, FRAMES)
    assert fit.roll_rad < 0 and abs(fit.roll_rad) > 4 * fit.roll_se
    assert 0.2 < fit.worst_corner_px < 0.8


def test_the_fit_recovers_exact_coefficients_through_outliers():
    rng = np.random.default_rng(3)
    w, h, cx, cy = 1000, 400, 510.0, 190.0
    u, v = rng.uniform(0, w, 3000), rng.uniform(0, h, 3000)
    a, b, c = -0.1, 2.5e-4, 6e-4
    y = a + b * (u - cx) + c * (v - cy) + rng.normal(0, 0.05, len(u))
    bad = rng.random(len(u)) < 0.08
    y[bad] += rng.choice([-1.0, 1.0], bad.sum()) * rng.uniform(0.5, 1.4, bad.sum())
    fit = fit_row_misalignment(u, v, y, cx, cy, w, h)
    assert fit.offset_px == pytest.approx(a, abs=0.005)
    assert fit.roll_rad == pytest.approx(b, abs=1e-5)
    assert fit.row_scale == pytest.approx(c, abs=3e-5)
    assert fit.residual_px == pytest.approx(0.05, rel=0.2)
    assert fit.corners_px[1] == pytest.approx(a + b * (w - 1 - cx) + c * (0 - cy), abs=0.01)


def test_bad_input_is_refused_by_name():
    img = np.zeros((50, 60), np.uint8)
    with pytest.raises(ValueError, match="differ in size"):
        patch_row_offsets(img, np.zeros((50, 61), np.uint8), [10.0], [10.0], [8.0])
    with pytest.raises(ValueError, match="differ in length"):
        patch_row_offsets(img, img, [10.0, 11.0], [10.0], [8.0])
    with pytest.raises(ValueError, match="right image"):
        patch_row_offsets(img, None, [10.0], [10.0], [8.0])
    with pytest.raises(ValueError, match="need at least 10"):
        fit_row_misalignment([1.0, 2.0], [1.0, 2.0], [0.1, 0.2], 0.0, 0.0, 60, 50)


def test_the_tool_reports_kitti_and_refuses_a_missing_folder(tmp_path, capsys):
    out = tmp_path / "rows.json"
    assert check_main(["--dataset", "kitti", "--frames", "3", "--out", str(out)]) == 0   # within 0.5 px
    rec = json.loads(out.read_text())
    assert rec["n_matches"] > 200 and rec["roll_rad"] < 0
    assert "rows aligned within" in capsys.readouterr().out
    assert check_main(["--dataset", "kitti", "--frames", "3", "--warn-px", "0.1"]) == 1
    assert "WARNING: rows off by up to" in capsys.readouterr().out
    assert check_main(["--dataset", "kitti", "--path", str(tmp_path / "nowhere")]) == 2
    assert "nowhere" in capsys.readouterr().err
