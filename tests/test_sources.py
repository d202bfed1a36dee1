"""Dataset sources on the bundled real data (data/) and on broken copies of it.

The bundled data is part of the repository: if it is missing these tests fail
(they never skip).
"""
from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from canopy.sources import BUNDLED_DATA, FolderSource, StereoSource, open_source
from shared.errors import InputError
from shared.types import StereoFrame

EUROC = BUNDLED_DATA["euroc"]
KITTI = BUNDLED_DATA["kitti"]


def _copytree(src: Path, dst: Path) -> None:
    """Copy that stays writable even if the source files are read-only."""
    shutil.copytree(src, dst, copy_function=shutil.copyfile)
    for p in [dst, *dst.rglob("*")]:
        p.chmod(p.stat().st_mode | 0o200)


def test_bundled_data_present():
    # An explicit failure (not a skip) when someone drops the bundled data.
    assert (EUROC / "mav0" / "cam0" / "sensor.yaml").is_file(), f"bundled EuRoC data missing at {EUROC}"
    assert (KITTI / "calib.txt").is_file(), f"bundled KITTI data missing at {KITTI}"


@pytest.fixture(scope="module")
def euroc() -> StereoSource:
    return open_source("euroc")


@pytest.fixture(scope="module")
def kitti() -> StereoSource:
    return open_source("kitti")


def _y_errors(left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """ORB cross-checked matches with a small descriptor distance: (dy, dx) arrays."""
    orb = cv2.ORB_create(1500)
    kl, dl = orb.detectAndCompute(left, None)
    kr, dr = orb.detectAndCompute(right, None)
    matches = [m for m in cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(dl, dr) if m.distance < 40]
    pl = np.array([kl[m.queryIdx].pt for m in matches])
    pr = np.array([kr[m.trainIdx].pt for m in matches])
    return pl[:, 1] - pr[:, 1], pl[:, 0] - pr[:, 0]


# -- EuRoC -----------------------------------------------------------------------

def test_euroc_frames_and_calibration(euroc):
    assert len(euroc) == 95  # cam1/data.csv lists 99, only 95 exist on both sides
    assert euroc.image_size == (752, 480)
    cal = euroc.calibration
    assert abs(cal.baseline - 0.110) < 0.003
    assert 400 < cal.fx < 500 and cal.fx == pytest.approx(cal.fy)
    assert euroc.rate_hz == pytest.approx(20.0)
    assert euroc.timestamps.dtype == np.float64
    assert np.allclose(np.diff(euroc.timestamps), 0.05, atol=1e-6)
    assert euroc.timestamps[0] == pytest.approx(1403715273.262142976, abs=1e-6)

    frame = euroc.frame(3)
    assert isinstance(frame, StereoFrame) and frame.index == 3
    assert frame.timestamp == euroc.timestamps[3]
    for img in (frame.left, frame.right):
        assert img.dtype == np.uint8 and img.shape == (480, 752)


def test_euroc_ground_truth(euroc):
    gt = euroc.ground_truth
    assert gt is not None and len(gt) >= 90
    idx = np.asarray(gt.meta["frame_indices"])
    np.testing.assert_array_equal(gt.stamps, euroc.timestamps[idx])  # stamps of the matched frames
    R = gt.poses[:, :3, :3]
    np.testing.assert_allclose(R @ R.transpose(0, 2, 1), np.broadcast_to(np.eye(3), R.shape), atol=1e-9)
    # The MAV sits still in this span: camera moves < 2.5 mm from where it started.
    p = gt.positions
    assert np.linalg.norm(p - p[0], axis=1).max() < 0.0025
    # Convention check: camera y (image down) points roughly along world -z (EuRoC world z is up).
    assert (R[:, 2, 1] < -0.8).all()


def test_euroc_rectification_aligns_rows(euroc):
    frame = euroc.frame(0)
    dy, dx = _y_errors(frame.left, frame.right)
    assert len(dy) > 100
    assert np.median(np.abs(dy)) < 0.5
    assert np.median(dx) > 0  # rectified right camera sits to the right: positive disparity
    raw_left, raw_right = euroc.raw_pair(0)
    raw_dy, _ = _y_errors(raw_left, raw_right)
    assert np.median(np.abs(raw_dy)) > np.median(np.abs(dy))


def test_euroc_iteration_and_max_frames():
    src = open_source("euroc", str(EUROC / "mav0"), max_frames=4)  # the mav0 folder itself works too
    frames = list(src)
    assert len(src) == 4 and [f.index for f in frames] == [0, 1, 2, 3]
    assert len(src.ground_truth) <= 4


# -- KITTI -------------------------------------------------------------------------

def test_kitti_frames_and_calibration(kitti):
    assert len(kitti) == 51
    assert kitti.image_size == (1226, 370)
    assert abs(kitti.calibration.baseline - 0.537) < 0.002
    assert kitti.calibration.fx == pytest.approx(707.0912)
    assert 9 < kitti.rate_hz < 11
    f = kitti.frame(50)
    assert f.left.shape == (370, 1226) and f.left.dtype == np.uint8


def test_kitti_ground_truth(kitti):
    gt = kitti.ground_truth
    assert gt is not None and len(gt) == 51
    np.testing.assert_allclose(gt.poses[0], np.eye(4), atol=1e-9)
    assert abs(gt.path_length() - 59.9) < 1.0
    assert gt.positions[-1, 2] > 55  # drives forward along camera z


def test_kitti_official_calib_form_matches_bare(tmp_path, kitti):
    seq = tmp_path / "06"
    _copytree(KITTI, seq)
    P = np.loadtxt(KITTI / "calib.txt").reshape(2, 12)
    lines = [f"P{i}: " + " ".join(f"{v:.12e}" for v in P[min(i, 1)]) for i in range(4)]
    lines.append("Tr: " + " ".join(f"{v:.12e}" for v in np.eye(4)[:3].ravel()))
    (seq / "calib.txt").write_text("\n".join(lines) + "\n")
    src = open_source("kitti", seq)
    assert src.calibration == kitti.calibration


def test_kitti_subset_of_images_matched_by_index(tmp_path):
    seq = tmp_path / "seq"
    seq.mkdir()
    for f in ("calib.txt", "times.txt", "poses.txt"):
        shutil.copyfile(KITTI / f, seq / f)
    for side in ("image_l", "image_r"):
        (seq / side).mkdir()
        for i in (10, 11, 12):
            shutil.copyfile(KITTI / side / f"{i:06d}.png", seq / side / f"{i:06d}.png")
    src = open_source("kitti", seq)
    times = np.loadtxt(KITTI / "times.txt")
    np.testing.assert_allclose(src.timestamps, times[10:13])
    poses = np.loadtxt(KITTI / "poses.txt").reshape(-1, 3, 4)
    np.testing.assert_allclose(src.ground_truth.poses[:, :3, :], poses[10:13])


# -- plain folder -------------------------------------------------------------------

def _make_folder(root: Path, n: int = 3, **calib) -> Path:
    (root / "left").mkdir(parents=True)
    (root / "right").mkdir()
    for i in range(n):
        shutil.copyfile(KITTI / "image_l" / f"{i:06d}.png", root / "left" / f"f{i:03d}.png")
        shutil.copyfile(KITTI / "image_r" / f"{i:06d}.png", root / "right" / f"f{i:03d}.png")
    values = {"fx": 707.0912, "fy": 707.0912, "cx": 601.8873, "cy": 183.1104, "baseline": 0.5371506}
    values.update(calib)
    (root / "calib.yaml").write_text(yaml.safe_dump({k: v for k, v in values.items() if v is not None}))
    return root


def test_folder_source(tmp_path, kitti):
    root = _make_folder(tmp_path / "stereo", rate_hz=10)
    src = open_source("folder", root)
    assert isinstance(src, FolderSource) and len(src) == 3
    assert src.image_size == (1226, 370)
    np.testing.assert_allclose(src.timestamps, [0.0, 0.1, 0.2])
    assert src.ground_truth is None
    np.testing.assert_array_equal(src.frame(2).left, kitti.frame(2).left)

    # times.txt and a TUM ground truth (qx qy qz qw order) are picked up.
    (root / "times.txt").write_text("0.0\n0.104\n0.208\n")
    (root / "groundtruth.txt").write_text(
        "# t x y z qx qy qz qw\n0.0 0 0 0 0 0 0 1\n0.1041 0 0 1 0 0 0.7071068 0.7071068\n"
    )
    src = open_source("folder", root, max_frames=2)
    np.testing.assert_allclose(src.timestamps, [0.0, 0.104])
    gt = src.ground_truth
    assert len(gt) == 2 and gt.meta["frame_indices"] == [0, 1]
    np.testing.assert_allclose(gt.poses[1, :3, :3], [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-6)


def test_folder_requires_path():
    with pytest.raises(InputError, match="path is required"):
        open_source("folder")


# -- bad input ----------------------------------------------------------------------

@pytest.mark.parametrize("kind", ["euroc", "kitti", "folder"])
def test_missing_folder(tmp_path, kind):
    missing = tmp_path / "nope"
    with pytest.raises(InputError) as err:
        open_source(kind, missing)
    assert "nope" in str(err.value) and "not found" in str(err.value)


def test_unknown_kind():
    with pytest.raises(InputError, match="unknown dataset kind"):
        open_source("tum")


def test_corrupt_png_names_the_file(tmp_path):
    seq = tmp_path / "kitti"
    _copytree(KITTI, seq)
    bad = seq / "image_r" / "000007.png"
    bad.write_bytes(b"\x89PNG\r\n\x1a\n this is not an image" * 10)
    src = open_source("kitti", seq)  # detected lazily, when the frame is read
    src.frame(6)
    with pytest.raises(InputError) as err:
        src.frame(7)
    assert "000007.png" in str(err.value)


def test_corrupt_euroc_png_names_the_file(tmp_path):
    seq = tmp_path / "euroc"
    _copytree(EUROC / "mav0" / "cam0", seq / "mav0" / "cam0")
    _copytree(EUROC / "mav0" / "cam1", seq / "mav0" / "cam1")
    src = open_source("euroc", seq)
    bad = src.left_paths[5]
    bad.write_bytes(b"garbage" * 100)
    with pytest.raises(InputError, match=bad.name):
        src.frame(5)


def test_calib_yaml_missing_baseline(tmp_path):
    root = _make_folder(tmp_path / "stereo", baseline=None)
    with pytest.raises(InputError) as err:
        open_source("folder", root)
    assert "baseline" in str(err.value) and "calib.yaml" in str(err.value)


def test_calib_yaml_non_numeric(tmp_path):
    root = _make_folder(tmp_path / "stereo", fx="wide")
    with pytest.raises(InputError, match="'fx' is not numeric"):
        open_source("folder", root)


def test_left_right_size_mismatch(tmp_path):
    root = _make_folder(tmp_path / "stereo")
    img = cv2.imread(str(root / "right" / "f001.png"), cv2.IMREAD_GRAYSCALE)
    cv2.imwrite(str(root / "right" / "f001.png"), img[:, :600])
    src = open_source("folder", root)
    with pytest.raises(InputError) as err:
        src.frame(1)
    msg = str(err.value)
    assert "f001.png" in msg and "600x370" in msg and "1226x370" in msg


def test_image_size_differs_from_calibration(tmp_path):
    seq = tmp_path / "euroc"
    _copytree(EUROC / "mav0" / "cam0", seq / "mav0" / "cam0")
    _copytree(EUROC / "mav0" / "cam1", seq / "mav0" / "cam1")
    src = open_source("euroc", seq)
    for p in (src.left_paths[0], src.right_paths[0]):
        cv2.imwrite(str(p), np.zeros((240, 376), np.uint8))
    with pytest.raises(InputError, match="calibration says 752x480"):
        src.frame(0)


def test_sensor_yaml_missing_intrinsics(tmp_path):
    seq = tmp_path / "euroc"
    _copytree(EUROC / "mav0" / "cam0", seq / "mav0" / "cam0")
    _copytree(EUROC / "mav0" / "cam1", seq / "mav0" / "cam1")
    yaml_path = seq / "mav0" / "cam1" / "sensor.yaml"
    yaml_path.write_text("\n".join(l for l in yaml_path.read_text().splitlines() if not l.startswith("intrinsics")))
    with pytest.raises(InputError) as err:
        open_source("euroc", seq)
    assert str(yaml_path) in str(err.value) and "intrinsics" in str(err.value)


def test_missing_sensor_yaml_and_times(tmp_path):
    seq = tmp_path / "euroc"
    _copytree(EUROC / "mav0" / "cam0", seq / "mav0" / "cam0")
    with pytest.raises(InputError, match="cam1"):
        open_source("euroc", seq)
    kseq = tmp_path / "kitti"
    _copytree(KITTI, kseq)
    (kseq / "times.txt").unlink()
    with pytest.raises(InputError, match="times.txt"):
        open_source("kitti", kseq)


def test_zero_frames(tmp_path):
    root = _make_folder(tmp_path / "stereo", n=0)
    with pytest.raises(InputError, match="no images"):
        open_source("folder", root)
