"""Stereo disparity uncertainty (canopy.frontend.keypoint_uncertainty): the Cramér-Rao disparity sigma
predicts which stereo matches scatter, on a generated stereo pair with an exact disparity.

The KITTI cases pin ``subpixel_raw_vertex_search`` to 0 (s31): their rules were built on, and are tested
against, the smoothed pair's own SAD vertex; the raw vertex leaves fewer scattered far points to act on
(tests/test_stereo_denoise.py)."""
import cv2
import numpy as np

from canopy.frontend.keypoint_uncertainty import disparity_sigma
from canopy.frontend.stereo import subpixel_refine

SCALES = 1.2 ** np.arange(8)
DISPARITY = 12.0


def _scene(seed: int, contrast: np.ndarray) -> np.ndarray:
    """A smooth random texture whose contrast varies across the columns (haze's transmission t
    falling from 1 to ~0.1 left to right), around grey 128."""
    rng = np.random.default_rng(seed)
    tex = cv2.GaussianBlur(rng.normal(0, 1, (240, len(contrast))).astype(np.float32), (0, 0), 1.5)
    tex /= tex.std()
    return 128.0 + 40.0 * tex * contrast[None, :]


def _pair(seed: int, noise: float):
    contrast = np.linspace(1.0, 0.1, 400 + int(DISPARITY)).astype(np.float32)
    wide = _scene(seed, contrast)  # (240, 412): the right image sees the same scene shifted
    left = wide[:, :-int(DISPARITY)]   # scene column X: left at X, right at X - 12 (disparity 12)
    right = wide[:, int(DISPARITY):]
    rng = np.random.default_rng(seed + 100)
    noisy = [np.clip(im + rng.normal(0, noise, im.shape), 0, 255).astype(np.uint8) for im in (left, right)]
    return noisy[0], noisy[1]


def test_disparity_sigma_predicts_the_scatter_of_sad_disparities():
    """Keypoints on a grid over the pair; the SAD refinement's disparity error (exact truth: 12 px)
    is several times larger where the bound is largest than where it is smallest, and the bound
    grows as the contrast falls (1/t)."""
    noise = 6.0
    errors, sigmas, cols = [], [], []
    for seed in range(3):
        left, right = _pair(seed, noise)
        ys, xs = np.mgrid[20:220:8, 30:370:8]
        uv = np.stack([xs.ravel(), ys.ravel()], axis=1).astype(np.float64)
        octave = np.zeros(len(uv), np.int32)
        ur0 = uv[:, 0] - DISPARITY + np.round(np.random.default_rng(seed).uniform(-2, 2, len(uv)))
        ur, _, ok = subpixel_refine(left, right, uv, ur0, octave, SCALES, 5, 5)
        sd = disparity_sigma(left, uv.astype(np.float32), octave, SCALES, noise, 5)
        errors.append(np.where(ok, uv[:, 0] - ur - DISPARITY, np.nan))
        sigmas.append(sd)
        cols.append(uv[:, 0])
    err, sd, col = np.concatenate(errors), np.concatenate(sigmas), np.concatenate(cols)
    # the bound follows the contrast: left third (t ~ 0.8-1) against the right third (t ~ 0.1-0.4)
    assert np.median(sd[col < 140]) * 2.5 < np.median(sd[col > 260])
    ok = np.isfinite(err)
    lo = ok & (sd <= np.quantile(sd, 0.25))
    hi = ok & (sd >= np.quantile(sd, 0.75))
    rms_lo = np.sqrt(np.mean(np.clip(err[lo], -5, 5) ** 2))
    rms_hi = np.sqrt(np.mean(np.clip(err[hi], -5, 5) ** 2))
    assert rms_hi > 2.5 * rms_lo, (rms_lo, rms_hi)
    # and it is a bound of the right size where the signal is strong: within a factor 3 of the scatter
    assert np.median(sd[lo]) < 3 * rms_lo and rms_lo < 3 * np.median(sd[lo]) + 0.1


def test_noise_only_windows_get_no_bound_and_clean_texture_a_small_one():
    rng = np.random.default_rng(0)
    flat = np.clip(128 + rng.normal(0, 6.0, (100, 100)), 0, 255).astype(np.uint8)
    uv = np.array([[50.0, 50.0], [30.0, 60.0]], np.float32)
    oc = np.zeros(2, np.int32)
    # a flat patch: its gradients are the noise's (the tensor's noise part removed, little or no signal)
    sd = disparity_sigma(flat, uv, oc, SCALES, 6.0, 5)
    assert np.all(~np.isfinite(sd) | (sd > 1.0)), sd
    left, _ = _pair(0, 1.0)
    sd = disparity_sigma(left, np.array([[60.0, 100.0]], np.float32), np.zeros(1, np.int32), SCALES, 1.0, 5)
    assert sd[0] < 0.05


# ---------------------------------------------------------------- the tracker's rule on a real pair
from dataclasses import replace  # noqa: E402
from pathlib import Path  # noqa: E402

from canopy.config import load_run_config  # noqa: E402
from canopy.degrade import (NOISE_LEVELS, DegradeParams, degrade_image, depth_from_stereo, disparity_sgbm,  # noqa: E402
                            ray_length)
from canopy.frontend import Tracker  # noqa: E402
from canopy.sources import open_source  # noqa: E402
from shared.types import StereoFrame  # noqa: E402

KITTI = Path(__file__).resolve().parents[1] / "data" / "kitti06_snippet"


def _first_keyframe(frame, params, calib):
    tracker = Tracker(calib, params)
    res = tracker.track(frame)
    return tracker, res.keyframe


def _hazy_kitti_pair(index: int, rng_left: int):
    """(source, clean KITTI 06 frame, the same pair with the grid's haze beta 0.06 from SGBM depth and the
    noisy sensor; noise seeds rng_left / rng_left + 1)."""
    src = open_source("kitti", KITTI)
    f = src.frame(index)
    ray = ray_length(depth_from_stereo(f.left, f.right, src.calibration), src.calibration)
    cell = DegradeParams(mode="haze+noise", beta=0.06, full_well=NOISE_LEVELS["high"][0],
                         read_noise=NOISE_LEVELS["high"][1])
    return src, f, StereoFrame(f.index, f.timestamp, degrade_image(f.left, cell, ray, rng=rng_left),
                               degrade_image(f.right, cell, ray, rng=rng_left + 1))


def test_uncertain_stereo_points_create_no_landmarks_and_the_rest_is_unchanged():
    """KITTI 06 frame 10 with the grid's haze (β 0.06) and noisy sensor: the rule leaves the stereo
    matches as they are, withholds landmarks from the points whose relative disparity bound is over the
    threshold (and only those), and those points' disparities are worse against the clean pair's SGBM
    than the kept ones'. Off, or on a clean pair (under the noise gate), the keyframe is the default's."""
    src, f, hazy = _hazy_kitti_pair(10, rng_left=0)
    base = replace(load_run_config("kitti").tracking, parallel_extraction=False,
                   subpixel_raw_vertex_search=0, uncertain_stereo_max_rel_sigma=0.0)
    rule = replace(base, uncertain_stereo_max_rel_sigma=0.05)  # the defaults: landmarks withheld, not bearing-only
    _, kf0 = _first_keyframe(hazy, base, src.calibration)
    tracker, kf1 = _first_keyframe(hazy, rule, src.calibration)
    np.testing.assert_array_equal(kf0.depth, kf1.depth)       # the matches are untouched
    np.testing.assert_array_equal(kf0.u_right, kf1.u_right)   # not bearing-only (that switch is off)
    uncertain = tracker._uncertain[1]
    made0, made1 = kf0.new_landmark_ids >= 0, kf1.new_landmark_ids >= 0
    np.testing.assert_array_equal(made1, made0 & ~uncertain)
    assert 0.03 * made0.sum() < (made0 & uncertain).sum() < 0.5 * made0.sum()
    # the withheld points' disparities against the clean pair's SGBM disparity at their pixel
    ref = disparity_sgbm(f.left, f.right).astype(float)
    uv = kf0.uv
    d_ref = ref[np.clip(np.rint(uv[:, 1]).astype(int), 0, ref.shape[0] - 1),
                np.clip(np.rint(uv[:, 0]).astype(int), 0, ref.shape[1] - 1)]
    d_est = uv[:, 0] - kf0.u_right
    scored = made0 & (d_ref > 0)
    # relative disparity error = relative depth error of the landmark the point would make
    rel = np.abs(d_est - d_ref) / np.maximum(d_ref, 1e-6)
    rel_withheld, rel_kept = np.median(rel[scored & uncertain]), np.median(rel[scored & ~uncertain])
    assert rel_withheld > 1.25 * rel_kept, (rel_withheld, rel_kept)  # 3.5 % against 2.5 % here
    # on the clean pair (robust noise sigma ~1.8 < 4) the rule does nothing
    _, c0 = _first_keyframe(f, base, src.calibration)
    _, c1 = _first_keyframe(f, rule, src.calibration)
    np.testing.assert_array_equal(c0.new_landmark_ids, c1.new_landmark_ids)
    np.testing.assert_array_equal(c0.u_right, c1.u_right)


def test_bearing_only_switch_drops_the_right_column_of_exactly_the_uncertain_points():
    src, f, hazy = _hazy_kitti_pair(20, rng_left=2)
    base = replace(load_run_config("kitti").tracking, parallel_extraction=False,
                   subpixel_raw_vertex_search=0, uncertain_stereo_max_rel_sigma=0.0)
    _, kf0 = _first_keyframe(hazy, base, src.calibration)
    tracker, kf1 = _first_keyframe(hazy, replace(base, uncertain_stereo_max_rel_sigma=0.05, uncertain_stereo_bearing_only=True,
                                                  uncertain_stereo_landmarks=True), src.calibration)
    uncertain = tracker._uncertain[1]
    assert uncertain.any()
    np.testing.assert_array_equal(kf1.u_right, np.where(uncertain, -1.0, kf0.u_right).astype(np.float32))
    np.testing.assert_array_equal(kf1.new_landmark_ids >= 0, kf0.new_landmark_ids >= 0)  # landmarks kept


def test_configs_turn_the_rule_on_for_kitti_only():
    assert load_run_config("kitti").tracking.uncertain_stereo_max_rel_sigma == 0.1
    assert not load_run_config("kitti").tracking.uncertain_stereo_bearing_only
    for name in ("euroc", "synthetic"):
        assert load_run_config(name).tracking.uncertain_stereo_max_rel_sigma == 0.0


def test_without_uncertain_depths_the_frame_after_initialisation_needs_no_retry():
    """KITTI frames 0-1 with haze 0.06 and the noisy sensor (tests/test_appearance_retry.py's pair): with
    the rule off, frame 1 (no velocity yet, a zero-motion prediction 1.2 m off) finds no RANSAC pose in
    the window matches and is only predicted; with the rule frame 0's map holds no depth the image
    cannot pin and frame 1 is tracked by RANSAC, without the appearance retry, within 5 cm of the truth."""
    from canopy.frontend.geometry import se3_inv
    src = open_source("kitti", KITTI, max_frames=2)
    frames = []
    cell = DegradeParams(mode="haze+noise", beta=0.06, full_well=NOISE_LEVELS["high"][0],
                         read_noise=NOISE_LEVELS["high"][1])
    for i in (0, 1):
        f = src.frame(i)
        ray_l = ray_length(depth_from_stereo(f.left, f.right, src.calibration), src.calibration)
        ray_r = ray_length(depth_from_stereo(f.left, f.right, src.calibration, view="right"), src.calibration)
        frames.append(StereoFrame(f.index, f.timestamp, degrade_image(f.left, cell, ray_l, rng=2 * i),
                                  degrade_image(f.right, cell, ray_r, rng=2 * i + 1)))
    # the zero-mean SAD on noisy haze off too (on in configs/kitti.yaml since s24): its better depths let frame 1
    # find its pose with the uncertain depths kept, which is not what this test is about
    p = replace(load_run_config("kitti").tracking, parallel_extraction=False,
                subpixel_raw_vertex_search=0, parallel_stereo=False,
                stereo_fill=False, appearance_retry=False, subpixel_mean_on_noisy_haze=False)
    status = {}
    for tau in (0.0, 0.1):
        tracker = Tracker(src.calibration, replace(p, uncertain_stereo_max_rel_sigma=tau))
        assert tracker.track(frames[0]).status == "init"
        res = tracker.track(frames[1])
        status[tau] = res.status
        if tau > 0:
            err = se3_inv(res.T_world_cam) @ src.ground_truth.poses[1]
            assert np.linalg.norm(err[:3, 3]) < 0.05
    assert status == {0.0: "predicted", 0.1: "ok"}


def test_noisy_frames_measure_far_points_bearing_only_and_keep_their_landmarks():
    """tracking.noisy_stereo_obs_max_depth_baselines (s30): on the noisy sensor's KITTI pair the stereo points
    beyond 40 baselines lose their right column (bearing-only in refinement and BA), the landmarks they make
    stay; on the clean pair (robust noise sigma under the gate) the keyframe is the default's."""
    src, f, hazy = _hazy_kitti_pair(20, rng_left=2)
    base = replace(load_run_config("kitti").tracking, parallel_extraction=False,
                   subpixel_raw_vertex_search=0, noisy_stereo_obs_max_depth_baselines=0.0)
    rule = replace(base, noisy_stereo_obs_max_depth_baselines=40.0)
    _, kf0 = _first_keyframe(hazy, base, src.calibration)
    _, kf1 = _first_keyframe(hazy, rule, src.calibration)
    far = (kf0.u_right >= 0) & (kf0.depth >= 40.0 * src.calibration.baseline)
    assert far.sum() > 20
    np.testing.assert_array_equal(kf1.u_right, np.where(far, -1.0, kf0.u_right).astype(np.float32))
    np.testing.assert_array_equal(kf1.new_landmark_ids >= 0, kf0.new_landmark_ids >= 0)
    _, c0 = _first_keyframe(f, base, src.calibration)
    _, c1 = _first_keyframe(f, rule, src.calibration)
    assert ((c0.u_right >= 0) & (c0.depth >= 40.0 * src.calibration.baseline)).sum() > 20   # far points exist
    np.testing.assert_array_equal(c0.u_right, c1.u_right)
