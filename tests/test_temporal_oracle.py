"""The exact-warp oracle of benchmarks/oracle_temporal.py (s22): the warp of frame t−k into frame t from the
renderer's poses and depth, and the N-frame average it makes of a noisy generated sequence."""
import importlib.util
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from canopy.frontend.geometry import se3_inv
from canopy.sources import open_source
from canopy.synthetic import generate_sequence

_spec = importlib.util.spec_from_file_location(
    "oracle_temporal", Path(__file__).resolve().parents[1] / "benchmarks" / "oracle_temporal.py")
ot = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(ot)

N_FRAMES, SIGMA = 6, 8.0


@pytest.fixture(scope="module")
def clean_and_noisy(tmp_path_factory):
    """A short generated day-loop (sensor noise off) and a copy with white Gaussian noise σ 8 on both cameras."""
    root = tmp_path_factory.mktemp("oracle")
    clean = generate_sequence("day-loop", root / "clean", n_frames=N_FRAMES, seed=3, workers=1,
                              start_offset_m=33.0, noise=False)
    noisy = root / "noisy"
    shutil.copytree(clean, noisy)
    rng = np.random.default_rng(0)
    for cam in ("cam0", "cam1"):
        for f in sorted((noisy / "mav0" / cam / "data").iterdir()):
            im = cv2.imread(str(f), cv2.IMREAD_UNCHANGED).astype(np.float64)
            cv2.imwrite(str(f), np.clip(np.rint(im + rng.normal(0.0, SIGMA, im.shape)), 0, 255).astype(np.uint8))
    return Path(clean), noisy


def _depth(path: Path, i: int) -> np.ndarray:
    f = sorted((path / "mav0" / "depth0" / "data").iterdir())[i]
    d = cv2.imread(str(f), cv2.IMREAD_UNCHANGED).astype(np.float32) / 1000.0
    return np.where(d > 0, np.minimum(d, 200.0), 200.0).astype(np.float32)


def test_exact_warp_maps_the_previous_frame_onto_the_current(clean_and_noisy):
    clean, _ = clean_and_noisy
    src = open_source("euroc", clean)
    c = src.calibration
    K = np.array([[c.fx, 0, c.cx], [0, c.fy, c.cy], [0, 0, 1.0]])
    gt = src.ground_truth.poses
    t = N_FRAMES - 1
    cur, prev = src.frame(t).left.astype(np.float32), src.frame(t - 2).left.astype(np.float32)
    mx, my, ok = ot.warp_maps(_depth(clean, t), _depth(clean, t - 2), se3_inv(gt[t - 2]) @ gt[t], K, 0.03)
    warped = cv2.remap(prev, mx, my, cv2.INTER_LINEAR)
    assert ok.mean() > 0.9
    rms_warped = np.sqrt(np.mean((warped - cur)[ok] ** 2))
    rms_unwarped = np.sqrt(np.mean((prev - cur) ** 2))
    assert rms_warped < 0.4 * rms_unwarped
    # a wrong pose (the identity) does not map it
    mx0, my0, ok0 = ot.warp_maps(_depth(clean, t), _depth(clean, t - 2), np.eye(4), K, 0.03)
    wrong = cv2.remap(prev, mx0, my0, cv2.INTER_LINEAR)
    assert np.sqrt(np.mean((wrong - cur)[ok0] ** 2)) > 2.0 * rms_warped


def test_average_of_four_warped_frames_lowers_the_noise_and_keeps_the_first_frame(clean_and_noisy, tmp_path):
    clean, noisy = clean_and_noisy
    out = tmp_path / "avg4"
    info = ot.average_folder(noisy, out, n=4, tol=0.03)
    # frames 0, 1, 2 have 1, 2, 3 samples, the rest up to 4 (6 frames: at most 3 on average)
    assert info["frames"] == N_FRAMES and 2.7 < info["mean_samples_per_pixel"] <= 3.0
    a, n, c = open_source("euroc", out), open_source("euroc", noisy), open_source("euroc", clean)
    # frame 0 has no past: written as it was
    np.testing.assert_array_equal(a.frame(0).left, n.frame(0).left)
    np.testing.assert_array_equal(a.frame(0).right, n.frame(0).right)
    t = N_FRAMES - 1
    for side in ("left", "right"):
        truth = getattr(c.frame(t), side).astype(np.float64)
        err_noisy = np.sqrt(np.mean((getattr(n.frame(t), side) - truth) ** 2))
        err_avg = np.sqrt(np.mean((getattr(a.frame(t), side) - truth) ** 2))
        assert err_noisy > 0.9 * SIGMA
        assert err_avg < 0.75 * err_noisy, (side, err_avg, err_noisy)
