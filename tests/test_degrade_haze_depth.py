"""The tool's SGBM haze depth against the renderer's exact depth (s22-hazepaint).

Haze painted from SGBM depth puts too little airlight on far surfaces, sky and the background side of
depth edges (SGBM "measures" textureless sky by its smoothness term and fattens near objects);
``depth_for_haze`` (``--haze-depth stereo-sky``, KITTI's default) keeps SGBM only where the image has
texture, fills holes from the farthest neighbour in row and column and makes sky far."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from canopy.degrade import DegradeParams, depth_for_haze, fill_disparity_sky, texture_mask
from canopy.sources import open_source
from tools.degrade_sequence import degrade_sequence

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from haze_depth_error import measure  # noqa: E402


@pytest.fixture(scope="module")
def dusk(tmp_path_factory):
    from canopy.synthetic import generate_sequence

    return generate_sequence("dusk-loop", tmp_path_factory.mktemp("dusk") / "seq", n_frames=1, seed=3, workers=1,
                             noise=False)


def test_sky_sgbm_haze_is_closer_to_the_exact_depth_haze(dusk):
    """A generated dusk-loop frame (trees, a dark ground, uniform sky), both cameras, β 0.06: the haze
    painted from ``depth_for_haze`` is nearer the exact-depth haze than the old SGBM haze everywhere it
    is measured -- near depth edges, away from them, and beyond 40 m. Measured with OpenCV 5.0.0: near 13.1
    -> 12.0, far 44.3 -> 26.2 grey levels (too little airlight: -44.3 -> -26.2); with 5.1.0, whose SGBM differs:
    near 8.0 -> 6.9, far 23.7 -> 2.4 (-23.7 -> -2.4). So the bounds are relative, plus the sign of the old error."""
    err = measure(dusk, 1, 0.06, 1.5)
    old, new = err["stereo"], err["stereo-sky"]
    assert new["near_abs"] < 0.95 * old["near_abs"]
    assert new["all_abs"] < 0.8 * old["all_abs"]
    assert new["far_abs"] < 0.7 * old["far_abs"]
    assert old["far_signed"] < -10.0 and new["far_signed"] > old["far_signed"]  # too near: too little airlight


def test_fill_disparity_sky_takes_the_farthest_neighbour_and_sky_is_far():
    d = np.zeros((5, 6), np.float32)
    d[1, :] = [0, 9, 9, 9, 9, 0]   # a near crown; nothing valid above it in columns 1-4: those are sky
    d[4, :] = [0, 2, 2, 2, 2, 0]   # the far ground below
    d[3, 1], d[3, 4] = 9, 9        # two trunks: the row between them is bounded by 9s, the column by 2
    out = fill_disparity_sky(d)
    assert out[0, 1:5].tolist() == [0, 0, 0, 0]          # sky: no valid pixel above
    assert out[3, 2:4].tolist() == [2, 2]                 # under the crown between the trunks: the far ground
    assert out[2, 2] == 2
    assert out[:, 0].tolist() == [0, 9, 0, 9, 2]         # a column with nothing valid: the row rule alone
    assert out[1, 1:5].tolist() == [9, 9, 9, 9]          # valid pixels are kept


def test_texture_mask_and_a_flat_pair_is_far():
    """No texture, no measurement: a uniform pair gives max_depth (sky), not the smoothness term's guess."""
    from shared.types import StereoCalibration

    calib = StereoCalibration(fx=400.0, fy=400.0, cx=160.0, cy=100.0, baseline=0.2, width=320, height=200)
    flat = np.full((200, 320), 120, np.uint8)
    assert not texture_mask(flat, 1.5).any()
    assert np.all(depth_for_haze(flat, flat, calib, max_depth=150.0, num_disparities=32) == 150.0)
    rng = np.random.default_rng(4)
    texture = rng.integers(0, 256, (200, 340), dtype=np.uint8)
    left, right = texture[:, :320].copy(), texture[:, 20:340].copy()
    depth = depth_for_haze(left, right, calib, max_depth=100.0, num_disparities=32)
    assert np.median(depth[20:-20, 40:-20]) == pytest.approx(calib.bf / 20, rel=1e-3)


def test_kitti_haze_records_the_new_depth(tmp_path):
    out = degrade_sequence("kitti", tmp_path / "k", DegradeParams(mode="haze", beta=0.06), max_frames=1)
    assert "haze_depth: stereo-sky" in (out / "DEGRADED.yaml").read_text()
    old = degrade_sequence("kitti", tmp_path / "o", DegradeParams(mode="haze", beta=0.06), max_frames=1,
                           haze_depth="stereo")
    assert "haze_depth: stereo\n" in (old / "DEGRADED.yaml").read_text()
    a, b = open_source("kitti", out).frame(0).left, open_source("kitti", old).frame(0).left
    assert a.shape == b.shape and np.any(a != b)
