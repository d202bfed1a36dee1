"""Trajectory file formats (real TUM / EuRoC / KITTI files) and the run's
output files (PLY, JSON, PNG)."""
from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from canopy import report
from canopy import trajectory_io as tio
from shared.errors import InputError
from shared.types import Trajectory

DATA = Path(__file__).resolve().parents[1] / "data"  # shipped with the project, see data/README.md
EVO = DATA / "evo_reference" / "test" / "data"


# --------------------------------------------------------------------------- quaternions

def test_quaternion_known_rotation_and_normalisation():
    h = np.sqrt(0.5)
    R = tio.quat_wxyz_to_rot([h, 0.0, 0.0, h])  # +90 deg about z
    np.testing.assert_allclose(R, [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-15)
    np.testing.assert_allclose(tio.quat_wxyz_to_rot([2.0, 0, 0, 0]), np.eye(3))
    np.testing.assert_allclose(tio.rot_to_quat_wxyz(R), [h, 0, 0, h], atol=1e-15)
    with pytest.raises(ValueError):
        tio.quat_wxyz_to_rot([0.0, 0.0, 0.0, 0.0])


def test_quaternion_roundtrip_vectorised():
    rng = np.random.default_rng(0)
    q = rng.normal(size=(500, 4))
    q[:3] = [[0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]  # 180-degree cases, w = 0
    R = tio.quat_wxyz_to_rot(q)
    assert R.shape == (500, 3, 3)
    np.testing.assert_allclose(np.einsum("nji,njk->nik", R, R), np.tile(np.eye(3), (500, 1, 1)),
                               atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    q2 = tio.rot_to_quat_wxyz(R)
    qn = q / np.linalg.norm(q, axis=1, keepdims=True)
    # same rotation, up to the quaternion sign
    assert np.allclose(np.abs(np.sum(q2 * qn, axis=1)), 1.0, atol=1e-12)
    np.testing.assert_allclose(tio.quat_wxyz_to_rot(q2), R, atol=1e-12)


# --------------------------------------------------------------------------- real files

def test_tum_fr1_xyz_groundtruth():
    traj = tio.read_tum(EVO / "freiburg1_xyz-groundtruth.txt")
    assert len(traj) == 3000  # 3003 lines, 3 comment lines
    assert traj.stamps[0] == pytest.approx(1305031098.6659, abs=1e-6)
    # first row: 1305031098.6659 1.3563 0.6305 1.6380 0.6132 0.5962 -0.3311 -0.3986
    np.testing.assert_allclose(traj.positions[0], [1.3563, 0.6305, 1.6380])
    q = np.array([-0.3986, 0.6132, 0.5962, -0.3311])
    np.testing.assert_allclose(traj.poses[0, :3, :3], tio.quat_wxyz_to_rot(q), atol=1e-15)
    assert np.all(np.diff(traj.stamps) > 0)
    assert traj.meta["format"] == "tum"
    est = tio.read_tum(EVO / "freiburg1_xyz-rgbdslam.txt")
    assert len(est) == 788


def test_euroc_csv_v102_groundtruth():
    traj = tio.read_euroc_csv(EVO / "V102_groundtruth.csv")
    assert len(traj) == 16702
    # 1403715524907143168 ns
    assert traj.stamps[0] == pytest.approx(1403715524.907143168, abs=1e-6)
    assert traj.stamps[1] - traj.stamps[0] == pytest.approx(0.004999936, abs=1e-6)
    np.testing.assert_allclose(traj.positions[0], [0.515356, 1.996773, 0.971104])
    q_wxyz = [0.161996, 0.789985, -0.205376, 0.554528]
    np.testing.assert_allclose(traj.poses[0, :3, :3], tio.quat_wxyz_to_rot(q_wxyz), atol=1e-15)
    assert traj.meta["frame"] == "T_world_body"


def test_kitti_poses_with_times():
    traj = tio.read_kitti(EVO / "KITTI_00_gt.txt", EVO / "KITTI_00_gt_times.txt")
    assert len(traj) == 4541
    assert traj.stamps[1] == pytest.approx(0.1037359)
    np.testing.assert_allclose(traj.poses[0], np.eye(4), atol=1e-8)
    plain = tio.read_kitti(EVO / "KITTI_00_ORB.txt")
    assert plain.stamps[:3].tolist() == [0.0, 1.0, 2.0]
    with pytest.raises(InputError, match="4540 timestamps for 4541 poses"):
        tio.read_kitti(EVO / "KITTI_00_gt.txt", np.arange(4540.0))


def test_read_trajectory_auto_detects_format():
    assert tio.read_trajectory(EVO / "V102.txt").meta["format"] == "tum"
    assert tio.read_trajectory(EVO / "KITTI_00_SPTAM.txt").meta["format"] == "kitti"
    assert tio.read_trajectory(EVO / "V102_groundtruth.csv").meta["format"] == "euroc"


# --------------------------------------------------------------------------- writing

def test_tum_write_read_roundtrip(tmp_path):
    src = tio.read_tum(EVO / "freiburg1_xyz-rgbdslam.txt")
    out = tio.write_tum(tmp_path / "run" / "traj.tum", src)
    back = tio.read_tum(out)
    np.testing.assert_allclose(back.stamps, src.stamps, atol=1e-6)
    np.testing.assert_allclose(back.poses, src.poses, atol=1e-8)
    first = [l for l in out.read_text().splitlines() if not l.startswith("#")][0]
    assert first.split()[0] == "1305031102.160407066"  # float64 of ...102.160407, 9 decimals


def test_kitti_write_read_roundtrip(tmp_path):
    src = tio.read_kitti(EVO / "KITTI_00_ORB.txt")
    back = tio.read_kitti(tio.write_kitti(tmp_path / "poses.txt", src))
    np.testing.assert_allclose(back.poses, src.poses, rtol=1e-9, atol=1e-12)


# --------------------------------------------------------------------------- bad input

@pytest.mark.parametrize("body, line, words", [
    ("# c\n1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 1\n", 3, "expected 8 numbers"),
    ("1.0 0 0 0 0 0 0 1\n\n2.0 0 x 0 0 0 0 1\n", 3, "not a number"),
    ("1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 0 0\n", 2, "zero norm"),
    ("1.0 0 0 nan 0 0 0 1\n", 1, "non-finite"),
])
def test_corrupt_tum_names_file_and_line(tmp_path, body, line, words):
    p = tmp_path / "bad_traj.txt"
    p.write_text(body)
    with pytest.raises(InputError) as exc:
        tio.read_tum(p)
    msg = str(exc.value)
    assert "bad_traj.txt" in msg and f"line {line}" in msg and words in msg
    assert exc.value.source == str(p)


def test_corrupt_euroc_and_kitti_name_file_and_line(tmp_path):
    header = open(EVO / "V102_groundtruth.csv").readline()
    p = tmp_path / "data.csv"
    p.write_text(header + "1403715524907143168,0.5,2.0,0.9,1,0,0,0\n"
                 "1403715524912143104,0.5,2.0\n")
    with pytest.raises(InputError, match=r"data\.csv: line 3: expected at least 8 columns"):
        tio.read_euroc_csv(p)
    p.write_text(header + "14037155249x7143168,0.5,2.0,0.9,1,0,0,0\n")
    with pytest.raises(InputError, match=r"data\.csv: line 2: not a number"):
        tio.read_euroc_csv(p)
    k = tmp_path / "poses.txt"
    k.write_text("1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0 0 1 0 0 0 0 1\n")
    with pytest.raises(InputError, match=r"poses\.txt: line 2: expected 12 numbers"):
        tio.read_kitti(k)
    with pytest.raises(InputError, match="not found"):
        tio.read_tum(tmp_path / "missing.txt")
    (tmp_path / "empty.txt").write_text("# only a comment\n")
    with pytest.raises(InputError, match="no TUM trajectory rows"):
        tio.read_tum(tmp_path / "empty.txt")


# --------------------------------------------------------------------------- output files

def _parse_ply(path: Path) -> tuple[dict, str, bytes]:
    raw = path.read_bytes()
    head, _, body = raw.partition(b"end_header\n")
    lines = head.decode("ascii").splitlines()
    assert lines[0] == "ply"
    fmt = lines[1].split()[1]
    counts = {l.split()[1]: int(l.split()[2]) for l in lines if l.startswith("element")}
    return counts, fmt, body


def test_ply_points_binary_and_ascii(tmp_path):
    rng = np.random.default_rng(0)
    xyz = rng.normal(size=(100, 3))
    xyz[5] = np.nan  # dropped
    col = rng.integers(0, 256, size=(100, 3)).astype(np.uint8)
    counts, fmt, body = _parse_ply(report.write_ply_points(tmp_path / "map.ply", xyz, col))
    assert counts == {"vertex": 99} and fmt == "binary_little_endian"
    rec = np.frombuffer(body, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"),
                                     ("r", "u1"), ("g", "u1"), ("b", "u1")])
    assert len(rec) == 99
    keep = np.ones(100, bool)
    keep[5] = False
    np.testing.assert_allclose(np.stack([rec["x"], rec["y"], rec["z"]], 1), xyz[keep], rtol=1e-6)
    assert np.array_equal(np.stack([rec["r"], rec["g"], rec["b"]], 1), col[keep])

    counts, fmt, body = _parse_ply(report.write_ply_points(tmp_path / "a.ply", xyz[10:20],
                                                           binary=False))
    assert counts == {"vertex": 10} and fmt == "ascii"
    np.testing.assert_allclose(np.loadtxt(body.decode().splitlines()), xyz[10:20], rtol=1e-6)


def test_ply_lines_have_vertices_and_edges(tmp_path):
    ep = np.arange(4 * 2 * 3, dtype=float).reshape(4, 2, 3)
    counts, fmt, body = _parse_ply(report.write_ply_lines(tmp_path / "lines.ply", ep))
    assert counts == {"vertex": 8, "edge": 4}
    verts = np.frombuffer(body[:8 * 12], dtype="<f4").reshape(8, 3)
    edges = np.frombuffer(body[8 * 12:], dtype="<i4").reshape(4, 2)
    np.testing.assert_array_equal(verts, ep.reshape(8, 3))
    assert edges.tolist() == [[0, 1], [2, 3], [4, 5], [6, 7]]
    counts, fmt, body = _parse_ply(report.write_ply_lines(tmp_path / "l.ply", ep, binary=False))
    assert counts == {"vertex": 8, "edge": 4} and len(body.decode().splitlines()) == 12


def test_write_json_handles_numpy(tmp_path):
    obj = {"a": np.float32(1.5), "b": np.arange(3), "c": {"d": np.int64(7), "e": np.nan},
           "f": (np.bool_(True), None)}
    back = json.loads(report.write_json(tmp_path / "m" / "metrics.json", obj).read_text())
    assert back == {"a": 1.5, "b": [0, 1, 2], "c": {"d": 7, "e": None}, "f": [True, None]}


def test_plot_trajectory_png_headless(tmp_path):
    gt = tio.read_tum(EVO / "freiburg1_xyz-groundtruth.txt")
    est = tio.read_tum(EVO / "freiburg1_xyz-rgbdslam.txt")
    p = report.plot_trajectory_png(tmp_path / "traj.png", est, gt, title="fr1_xyz")
    img = cv2.imread(str(p))
    assert img is not None and img.shape[0] > 100 and img.shape[1] > 100
    p2 = report.plot_trajectory_png(tmp_path / "est_only.png", est, None)
    assert cv2.imread(str(p2)) is not None
    single = Trajectory([0.0], np.eye(4)[None])
    assert cv2.imread(str(report.plot_trajectory_png(tmp_path / "one.png", single, None))) is not None
