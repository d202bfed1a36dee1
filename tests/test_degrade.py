"""Low-light and haze degradation (canopy.degrade) and the dataset tool (tools/degrade_sequence.py)."""
from __future__ import annotations

import numpy as np
import pytest

from canopy.degrade import (DegradeParams, add_haze, darken, degrade_image, depth_from_rendered, depth_from_stereo,
                            fill_disparity_background, ray_length, transmission)
from canopy.sources import open_source
from shared.errors import ConfigError, InputError
from shared.types import StereoCalibration
from tools.degrade_sequence import degrade_sequence, resolve_haze_depth

FULL_WELL = 4000.0
READ_NOISE = 4.0


def flat(value: int, shape=(256, 256)) -> np.ndarray:
    return np.full(shape, value, np.uint8)


# -- low light -----------------------------------------------------------------------------

@pytest.mark.parametrize("gain", [0.5, 0.15, 0.05])
def test_darken_scales_mean_by_gain(gain):
    rng = np.random.default_rng(7)
    image = rng.integers(0, 256, (300, 400), dtype=np.uint8)
    out = darken(image, gain, FULL_WELL, READ_NOISE, rng=1)
    assert out.dtype == np.uint8 and out.shape == image.shape
    # Noise averages out over 120k pixels: the mean is gain * mean within 0.05 grey levels.
    assert out.mean() == pytest.approx(gain * image.mean(), abs=0.05)


@pytest.mark.parametrize("value", [40, 120, 240])
def test_darken_noise_is_poisson_plus_read_noise(value):
    gain = 0.2
    out = darken(flat(value, (512, 512)), gain, FULL_WELL, READ_NOISE, rng=3).astype(np.float64)
    electrons = gain * value / 255.0 * FULL_WELL
    dn_per_electron = 255.0 / FULL_WELL
    expected_var = dn_per_electron ** 2 * (electrons + READ_NOISE ** 2) + 1.0 / 12.0  # + quantisation
    assert out.mean() == pytest.approx(gain * value, abs=0.02)
    assert out.var() == pytest.approx(expected_var, rel=0.05)


def test_darken_variance_grows_with_signal():
    variances = [darken(flat(v, (512, 512)), 0.3, FULL_WELL, 0.0, rng=5).astype(float).var()
                 for v in (30, 90, 180, 250)]
    assert all(b > a for a, b in zip(variances, variances[1:]))
    # shot noise only: variance proportional to the signal (ratio 250/30, quantisation aside)
    assert variances[-1] / variances[0] == pytest.approx(250 / 30, rel=0.25)


def test_darken_is_deterministic_with_the_seed():
    image = np.random.default_rng(0).integers(0, 256, (64, 80), dtype=np.uint8)
    a = darken(image, 0.1, rng=42)
    assert np.array_equal(a, darken(image, 0.1, rng=42))
    assert np.array_equal(a, darken(image, 0.1, rng=np.random.default_rng(42)))
    assert not np.array_equal(a, darken(image, 0.1, rng=43))


def test_darken_gamma_and_colour():
    image = np.full((50, 60, 3), 200, np.uint8)
    out = darken(image, 0.25, full_well=1e9, read_noise=0.0, gamma=2.2)  # noise-free limit
    expected = 255.0 * ((200 / 255.0) ** 2.2 * 0.25) ** (1 / 2.2)
    assert out.shape == image.shape
    assert np.abs(out.astype(float) - expected).max() <= 1.0


# -- haze ----------------------------------------------------------------------------------

def test_haze_with_constant_depth_is_the_analytic_formula():
    J = np.arange(256, dtype=np.uint8).reshape(16, 16)
    beta, A, depth = 0.07, 210.0, 12.5
    t = np.exp(-beta * depth)
    expected = np.rint(J.astype(np.float64) * t + A * (1.0 - t)).astype(np.uint8)
    assert np.array_equal(add_haze(J, depth, beta, A), expected)
    assert np.array_equal(add_haze(J, np.full(J.shape, depth), beta, A), expected)


def test_haze_per_pixel_depth_and_colour():
    J = np.random.default_rng(1).integers(0, 256, (20, 30, 3), dtype=np.uint8)
    depth = np.linspace(0.0, 80.0, 600).reshape(20, 30)
    t = np.exp(-0.05 * depth)[:, :, None]
    expected = np.rint(J * t + 200.0 * (1 - t)).astype(np.uint8)
    assert np.array_equal(add_haze(J, depth, 0.05, 200.0), expected)


def test_no_haze_when_beta_is_zero():
    J = np.random.default_rng(2).integers(0, 256, (40, 50), dtype=np.uint8)
    assert np.array_equal(add_haze(J, 1e6, 0.0, 255.0), J)
    assert np.array_equal(add_haze(J, np.full(J.shape, np.inf), 0.0, 255.0), J)
    assert np.all(transmission(np.array([0.0, 10.0, np.inf]), 0.0) == 1.0)
    # with a gamma the round trip is identity up to quantisation
    assert np.abs(add_haze(J, 5.0, 0.0, 100.0, gamma=2.2).astype(int) - J).max() <= 1


def test_far_haze_becomes_airlight():
    J = np.random.default_rng(3).integers(0, 256, (10, 10), dtype=np.uint8)
    assert np.all(add_haze(J, 1e4, 1.0, 180.0) == 180)


def test_depth_from_stereo_recovers_a_plane():
    """A textured fronto-parallel plane shifted by a known disparity: depth = bf / d."""
    calib = StereoCalibration(fx=400.0, fy=400.0, cx=160.0, cy=100.0, baseline=0.2, width=320, height=200)
    d = 20
    texture = np.random.default_rng(4).integers(0, 256, (200, 340), dtype=np.uint8)
    left, right = texture[:, :320].copy(), texture[:, d:d + 320].copy()  # right sees x - d
    depth = depth_from_stereo(left, right, calib, max_depth=100.0, num_disparities=32)
    inner = depth[20:-20, 40:-20]
    assert np.median(inner) == pytest.approx(calib.bf / d, rel=1e-3)
    # the left strip has no disparity: filled from the row's first valid pixel, not "far"
    assert np.median(depth[:, :20]) == pytest.approx(calib.bf / d, rel=1e-2)
    depth_r = depth_from_stereo(left, right, calib, max_depth=100.0, num_disparities=32, view="right")
    assert np.median(depth_r[20:-20, 20:-40]) == pytest.approx(calib.bf / d, rel=1e-3)
    rays = ray_length(depth, calib)
    assert rays[100, 160] == pytest.approx(depth[100, 160], rel=1e-6)  # ray = z at the principal point
    assert np.all(rays >= depth - 1e-4)


def test_depth_from_rendered_warps_the_left_depth_to_the_right_camera():
    """A near box (2 m) in front of a wall (20 m) with sky above: the right camera sees the box
    bf / 2 px further left, the wall it uncovers keeps the wall's depth, sky stays far."""
    calib = StereoCalibration(fx=400.0, fy=400.0, cx=160.0, cy=100.0, baseline=0.2, width=320, height=200)
    z = np.full((200, 320), 20.0)
    z[:50] = 0.0                      # sky: the renderer writes 0
    z[100:150, 150:200] = 2.0         # the box; its disparity bf / 2 = 40 px, the wall's 4 px
    left = depth_from_rendered(z, calib, max_depth=100.0)
    assert left[120, 160] == pytest.approx(2.0) and left[10, 10] == pytest.approx(100.0)
    right = depth_from_rendered(z, calib, max_depth=100.0, view="right")
    assert right[10, 100] == pytest.approx(100.0)                       # sky
    assert np.allclose(right[100:150, 110:160], 2.0)                     # the box, 40 px left
    assert np.allclose(right[100:150, 160:195], 20.0)                    # the wall behind it (occlusion filled far)
    assert np.allclose(right[60:90, 20:300], 20.0)                       # the wall elsewhere
    with pytest.raises(InputError, match="depth_left"):
        depth_from_rendered(z[:10], calib)
    with pytest.raises(ConfigError, match="view"):
        depth_from_rendered(z, calib, view="up")


def test_rendered_haze_depth_needs_a_generated_sequence(tmp_path):
    with pytest.raises(ConfigError, match="haze-depth"):
        degrade_sequence("kitti", tmp_path / "k", DegradeParams(mode="haze"), max_frames=1, haze_depth="rendered")
    with pytest.raises(InputError, match="depth0"):  # the bundled EuRoC snippet has no rendered depth
        degrade_sequence("euroc", tmp_path / "e", DegradeParams(mode="haze"), max_frames=1, haze_depth="rendered")
    assert not (tmp_path / "e").exists()  # refused before writing anything


def test_haze_depth_auto_is_sgbm_on_real_data():
    """auto: KITTI (outdoor) and the bundled EuRoC snippet (a hall; no rendered depth) get SGBM: KITTI the
    textured-SGBM, sky-far depth (``stereo-sky``, s22), EuRoC the plain one; a bad name is refused."""
    assert resolve_haze_depth("auto", "kitti") == "stereo-sky"
    assert resolve_haze_depth("stereo", "kitti") == "stereo"
    assert resolve_haze_depth("auto", "euroc") == "stereo"
    assert resolve_haze_depth("stereo", "euroc") == "stereo"
    with pytest.raises(ConfigError, match="haze-depth"):
        resolve_haze_depth("sgbm", "euroc")


def test_fill_disparity_takes_the_farther_neighbour():
    disp = np.array([[0, 8, 0, 0, 3, 0], [0, 0, 0, 0, 0, 0]], np.float32)
    assert fill_disparity_background(disp).tolist() == [[8, 8, 3, 3, 3, 3], [0, 0, 0, 0, 0, 0]]


# -- bad parameters --------------------------------------------------------------------------

@pytest.mark.parametrize("kwargs", [{"gain": 0.0}, {"gain": -1.0}, {"gain": float("nan")}, {"full_well": 0.0},
                                    {"read_noise": -1.0}, {"gamma": 0.0}, {"gain": True}])
def test_darken_rejects_bad_parameters(kwargs):
    args = {"gain": 0.1, **kwargs}
    with pytest.raises(ConfigError, match=next(iter(kwargs))):
        darken(flat(100, (4, 4)), **args)


@pytest.mark.parametrize("kwargs", [{"beta": -0.1}, {"airlight": 300.0}, {"airlight": -1.0},
                                    {"beta": float("inf")}])
def test_haze_rejects_bad_parameters(kwargs):
    args = {"beta": 0.1, "airlight": 200.0, **kwargs}
    with pytest.raises(ConfigError, match=next(iter(kwargs))):
        add_haze(flat(100, (4, 4)), 10.0, **args)


def test_bad_images_and_depths_are_input_errors():
    with pytest.raises(InputError, match="uint8"):
        darken(np.zeros((4, 4), np.float32), 0.5)
    with pytest.raises(InputError, match="depth"):
        add_haze(flat(100, (4, 4)), np.full((3, 3), 5.0), 0.1)
    with pytest.raises(InputError, match="depth"):
        add_haze(flat(100, (4, 4)), -1.0, 0.1)


@pytest.mark.parametrize("kwargs", [{"mode": "fog"}, {"gain": 0}, {"beta": -1}, {"num_disparities": 100},
                                    {"block_size": 4}, {"max_depth": 0}, {"seed": -1}])
def test_degrade_params_validate(kwargs):
    with pytest.raises(ConfigError):
        DegradeParams(**kwargs)


# -- the dataset tool ---------------------------------------------------------------------------

def _same_metadata(a, b):
    assert a.calibration == b.calibration
    np.testing.assert_array_equal(a.timestamps, b.timestamps)
    assert a.ground_truth is not None and b.ground_truth is not None
    np.testing.assert_array_equal(a.ground_truth.stamps, b.ground_truth.stamps)
    np.testing.assert_array_equal(a.ground_truth.poses, b.ground_truth.poses)


def test_degraded_kitti_copy_opens_unchanged(tmp_path):
    params = DegradeParams(mode="dark+haze", gain=0.2, beta=0.05, seed=3)
    out = degrade_sequence("kitti", tmp_path / "kitti", params, max_frames=3)
    clean = open_source("kitti", max_frames=3)
    dark = open_source("kitti", out)
    assert len(dark) == 3
    _same_metadata(dark, clean)
    for name in ("calib.txt", "times.txt", "poses.txt"):
        assert (out / name).read_bytes() == (clean.root / name).read_bytes()
    assert [p.parent.name for p in dark.left_paths[:1] + dark.right_paths[:1]] == ["image_l", "image_r"]
    f, g = dark.frame(0), clean.frame(0)
    assert f.left.shape == g.left.shape and f.left.dtype == np.uint8
    assert f.left.mean() < 0.5 * g.left.mean()
    # same seed, same files
    again = degrade_sequence("kitti", tmp_path / "again", params, max_frames=1)
    assert (again / "image_l" / "000000.png").read_bytes() == (out / "image_l" / "000000.png").read_bytes()


def test_degraded_euroc_copy_opens_unchanged(tmp_path):
    params = DegradeParams(mode="haze", beta=0.3, max_depth=20.0)
    out = degrade_sequence("euroc", tmp_path / "euroc", params, max_frames=2)
    clean = open_source("euroc", max_frames=2)
    hazy = open_source("euroc", out)
    assert len(hazy) == 2
    _same_metadata(hazy, clean)
    assert (out / "mav0" / "cam0" / "sensor.yaml").read_bytes() == \
        (clean.root / "mav0" / "cam0" / "sensor.yaml").read_bytes()
    # haze lifts the dark tones and lowers the contrast
    f, g = hazy.frame(0), clean.frame(0)
    assert np.percentile(f.left, 5) > np.percentile(g.left, 5) + 20
    assert f.left.std() < g.left.std()


def test_rendered_haze_follows_the_exact_depth_in_both_cameras(tmp_path):
    """On a generated sequence the default (--haze-depth auto) is the renderer's depth: the haze each
    camera gets is the model's I t + A (1 - t) with t from the renderer's depth (left) and its warp
    (right), so the transmission read back from the hazy / clean pair matches exp(-beta * ray) of that
    depth."""
    import cv2

    from canopy.synthetic import generate_sequence

    seq = generate_sequence("day-loop", tmp_path / "seq", n_frames=1, seed=3, workers=1, noise=False)
    assert resolve_haze_depth("auto", "euroc", seq) == "rendered"
    params = DegradeParams(mode="haze", beta=0.06, airlight=220.0, max_depth=200.0)
    out = degrade_sequence("euroc", tmp_path / "hazy", params, path=seq)  # default: auto
    clean, hazy = open_source("euroc", seq), open_source("euroc", out)
    c, h = clean.frame(0), hazy.frame(0)
    calib = clean.calibration
    z = cv2.imread(str(seq / "mav0" / "depth0" / "data" / clean.left_paths[0].name), cv2.IMREAD_UNCHANGED) / 1000.0
    for view, img_c, img_h in (("left", c.left, h.left), ("right", c.right, h.right)):
        t_model = np.exp(-params.beta * ray_length(depth_from_rendered(z, calib, params.max_depth, view), calib))
        I, J = img_h.astype(float), img_c.astype(float)
        ok = (params.airlight - J > 60) & (t_model > 0.2)   # well-conditioned: t = (A - I) / (A - J)
        ok[:, :8] = ok[:, -8:] = False                       # rectification borders
        t_read = (params.airlight - I[ok]) / (params.airlight - J[ok])
        assert ok.sum() > 1000
        assert np.median(np.abs(t_read - t_model[ok])) < 0.02, view
    assert "haze_depth: rendered" in (out / "DEGRADED.yaml").read_text()


def test_tool_refuses_to_overwrite_its_input(tmp_path):
    with pytest.raises(ConfigError, match="input"):
        degrade_sequence("kitti", open_source("kitti", max_frames=1).root, DegradeParams(), max_frames=1)
    (tmp_path / "busy").mkdir()
    (tmp_path / "busy" / "x").write_text("x")
    with pytest.raises(ConfigError, match="not empty"):
        degrade_sequence("kitti", tmp_path / "busy", DegradeParams(), max_frames=1)


# ---------------------------------------------------------------- the degradation grid (issue 9)

def test_grid_cells_cover_light_haze_and_noise():
    from canopy.degrade import GRID_BETAS, GRID_GAINS, NOISE_LEVELS, grid_cells

    cells = grid_cells()
    assert len(cells) == len(GRID_GAINS) * len(GRID_BETAS) * len(NOISE_LEVELS)
    labels = [c.label for c in cells]
    assert len(set(labels)) == len(labels)
    assert "g1-b0-low" in labels and "g0.02-b0.06-high" in labels
    by_label = dict(zip(labels, cells))
    assert by_label["g1-b0-high"].mode == "noise" and by_label["g1-b0.03-low"].mode == "haze+noise"
    assert by_label["g0.06-b0.06-high"].mode == "dark+haze"
    assert (by_label["g0.15-b0-high"].full_well, by_label["g0.15-b0-high"].read_noise) == NOISE_LEVELS["high"]
    with pytest.raises(ConfigError, match="noise"):
        grid_cells(noise_levels=("medium",))


def test_noise_mode_keeps_the_light_and_adds_sensor_noise():
    from canopy.degrade import NOISE_LEVELS

    image = np.full((200, 200), 128, np.uint8)
    full_well, read_noise = NOISE_LEVELS["high"]
    out = degrade_image(image, DegradeParams(mode="noise", gain=0.1, full_well=full_well, read_noise=read_noise),
                        rng=0)
    # gain is ignored without "dark": mean stays, variance is shot + read noise in grey levels
    expected_var = (255.0 / full_well) ** 2 * (128.0 * full_well / 255.0 + read_noise ** 2) + 1 / 12
    assert out.mean() == pytest.approx(128.0, abs=0.3)
    assert out.var() == pytest.approx(expected_var, rel=0.05)


def test_haze_plus_noise_needs_depth_and_applies_both():
    image = np.full((60, 80), 40, np.uint8)
    params = DegradeParams(mode="haze+noise", beta=0.06, airlight=220.0)
    with pytest.raises(ConfigError, match="depth"):
        degrade_image(image, params)
    out = degrade_image(image, params, ray_m=np.full((60, 80), 20.0), rng=0)
    t = np.exp(-0.06 * 20.0)
    assert out.mean() == pytest.approx(40 * t + 220 * (1 - t), abs=0.5)
    assert out.std() > 1.0


def test_tool_writes_a_grid_cell_with_a_named_noise_sensor(tmp_path):
    from tools.degrade_sequence import main

    out = tmp_path / "cell"
    assert main(["--dataset", "kitti", "--out", str(out), "--mode", "haze+noise", "--beta", "0.03",
                 "--noise", "high", "--max-frames", "2"]) == 0
    clean = open_source("kitti", max_frames=2)
    degraded = open_source("kitti", out)
    assert len(degraded) == 2
    a, b = clean.frame(1).left.astype(float), degraded.frame(1).left.astype(float)
    assert b.mean() > a.mean() + 5           # airlight added
    assert np.abs(b - a).std() > 3           # and the noisy sensor
    import yaml
    meta = yaml.safe_load((out / "DEGRADED.yaml").read_text())
    assert (meta["params"]["full_well"], meta["params"]["read_noise"]) == (1000.0, 10.0)


def test_rectify_nearest_is_an_exact_lookup_for_fixed_point_maps():
    """The rendered depth reaches the rectified view by nearest-neighbour lookup through the source's
    fixed-point (CV_16SC2) maps. With an identity map (the generated presets' cameras are already
    rectified) every value must come back unchanged, and a map shifted by one column must shift the
    values by exactly one column: OpenCV 5.0.0's nearest remap on such maps moved 90 % of the depth
    pixels, so the painted haze differed between OpenCV versions."""
    import cv2

    from tools.degrade_sequence import rectify_nearest

    h, w = 48, 64
    depth = np.random.default_rng(0).integers(1000, 60000, size=(h, w), dtype=np.uint16)
    u, v = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    identity = cv2.convertMaps(u, v, cv2.CV_16SC2)
    assert np.array_equal(rectify_nearest(depth, identity), depth)
    shifted = cv2.convertMaps(u + 1, v, cv2.CV_16SC2)
    assert np.array_equal(rectify_nearest(depth, shifted)[:, :-1], depth[:, 1:])
