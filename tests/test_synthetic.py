"""Generated orchard sequences: exact depth, projection, stereo consistency, EuRoC round trip.

One short noise-free sequence is generated once (module fixture) starting at
the exit of a U-turn, where the row-end posts and their white tags face the
camera; every geometric check compares the files a SLAM system would read
(sensor.yaml, ground-truth CSV, PNGs) with an independent float64 computation.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from canopy.sources import open_source
from canopy.synthetic import PRESETS, SequenceGenerator, generate_sequence, resolve_params
from canopy.synthetic.conditions import Conditions
from canopy.synthetic.renderer import GROUND, SKY, RenderOutput
from canopy.synthetic.scene import Layout, OrchardScene
from canopy.synthetic.trajectories import make_track, path_for
from shared.errors import ConfigError, InputError

REPO = Path(__file__).resolve().parents[1]
N_FRAMES = 10
SEED = 3
OPTS = dict(start_offset_m=33.0, noise=False)  # U-turn exit: end posts with tags ahead


@pytest.fixture(scope="module")
def seq(tmp_path_factory):
    out = tmp_path_factory.mktemp("syn") / "day"
    path = generate_sequence("day-loop", out, n_frames=N_FRAMES, seed=SEED, workers=1, **OPTS)
    gen = SequenceGenerator(resolve_params("day-loop", N_FRAMES, **OPTS), SEED)
    return path, open_source("euroc", path), gen


def _depth_png(path: Path, src, i: int) -> np.ndarray:
    name = src.left_paths[i].name
    d = cv2.imread(str(path / "mav0" / "depth0" / "data" / name), cv2.IMREAD_UNCHANGED)
    assert d is not None and d.dtype == np.uint16
    return d.astype(np.float64) / 1000.0


# -- independent float64 ray caster (no culling, no float32) ------------------------

def _analytic_depth(scene, T: np.ndarray, cal, uv: np.ndarray) -> np.ndarray:
    """Nearest hit depth (camera z) of the rays through pixels ``uv`` (N, 2); inf for sky."""
    rays = np.c_[(uv[:, 0] - cal.cx) / cal.fx, (uv[:, 1] - cal.cy) / cal.fy, np.ones(len(uv))]
    d = rays @ T[:3, :3].T  # world directions, camera z = 1
    o = T[:3, 3]
    best = np.full(len(uv), np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -o[2] / d[:, 2]
        best = np.where((d[:, 2] < 0) & (t > 0), t, best)
        for (a, b), r, h in zip(scene.trunk_xy, scene.trunk_r, scene.trunk_h):
            px, py = o[0] - a, o[1] - b
            A = d[:, 0] ** 2 + d[:, 1] ** 2
            B = 2 * (d[:, 0] * px + d[:, 1] * py)
            C = px**2 + py**2 - r**2
            disc = B**2 - 4 * A * C
            t = (-B - np.sqrt(disc)) / (2 * A)
            z = o[2] + t * d[:, 2]
            ok = (disc > 0) & (t > 0.05) & (z >= 0) & (z <= h)
            best = np.where(ok & (t < best), t, best)
        for c, (ra, rb) in zip(scene.canopy_c, scene.canopy_r):
            s = np.array([ra, ra, rb])
            oo, dd = (o - c) / s, d / s
            A = (dd**2).sum(1)
            B = 2 * dd @ oo
            C = oo @ oo - 1
            disc = B**2 - 4 * A * C
            t = (-B - np.sqrt(disc)) / (2 * A)
            ok = (disc > 0) & (t > 0.05)
            best = np.where(ok & (t < best), t, best)
        for lo, hi in zip(scene.post_lo, scene.post_hi):
            t1, t2 = (lo - o) / d, (hi - o) / d
            tn = np.minimum(t1, t2).max(1)
            tf = np.maximum(t1, t2).min(1)
            ok = (tn <= tf) & (tn > 0.05)
            best = np.where(ok & (tn < best), tn, best)
    return best


def test_depth_matches_analytic_primitives(seq):
    path, src, gen = seq
    rng = np.random.default_rng(0)
    cal = src.calibration
    for i in (0, N_FRAMES - 1):
        T = src.ground_truth.poses[i]
        uv = np.c_[rng.integers(0, cal.width, 600), rng.integers(0, cal.height, 600)].astype(np.float64)
        expect = _analytic_depth(gen.scene, T, cal, uv)
        rendered = gen.render_clean(i).depth[uv[:, 1].astype(int), uv[:, 0].astype(int)]
        written = _depth_png(path, src, i)[uv[:, 1].astype(int), uv[:, 0].astype(int)]
        hit = np.isfinite(expect) & (expect < 60)
        assert hit.sum() > 300
        np.testing.assert_array_equal(np.isfinite(rendered), np.isfinite(expect))
        rel = np.abs(rendered[hit] - expect[hit]) / expect[hit]
        # Pixels whose ray grazes a silhouette may flip between float32 and float64.
        assert np.mean(rel < 0.005) > 0.99, np.sort(rel)[-10:]
        assert np.median(rel) < 1e-4
        rel_w = np.abs(written[hit] - expect[hit]) / expect[hit]
        assert np.mean(rel_w < 0.005) > 0.99


def _tag_observations(path, src, gen, i):
    """For frame i: [(tag, z, predicted uv left)] for the tags clearly visible and facing the camera."""
    T = src.ground_truth.poses[i]
    cal = src.calibration
    T_cw = np.linalg.inv(T)
    depth = _depth_png(path, src, i)
    out = []
    for tag in gen.scene.tags:
        pc = T_cw[:3, :3] @ tag.center + T_cw[:3, 3]
        if pc[2] < 0.5:
            continue
        u, v = cal.fx * pc[0] / pc[2] + cal.cx, cal.fy * pc[1] / pc[2] + cal.cy
        half = cal.fx * gen.scene.tag_half / pc[2]
        if not (half > 4 and 3 * half < u < cal.width - 3 * half and 3 * half < v < cal.height - 3 * half):
            continue
        view = T[:3, 3] - tag.center
        if view @ tag.normal < 0.6 * np.linalg.norm(view):  # within ~53 degrees of the face normal
            continue
        if abs(depth[int(round(v)), int(round(u))] - pc[2]) > 0.02 * pc[2]:
            continue  # occluded
        out.append((tag, pc[2], np.array([u, v]), half))
    return out


def _white_centroid(img: np.ndarray, uv: np.ndarray, r: float) -> np.ndarray:
    """Centroid of the bright pixels in a window of half-size r around uv."""
    u0, u1 = int(np.floor(uv[0] - r)), int(np.ceil(uv[0] + r)) + 1
    v0, v1 = int(np.floor(uv[1] - r)), int(np.ceil(uv[1] + r)) + 1
    win = img[v0:v1, u0:u1].astype(np.float64)
    mask = win > 0.5 * (win.max() + win.min())
    ys, xs = np.nonzero(mask)
    return np.array([xs.mean() + u0, ys.mean() + v0])


def test_projected_tag_centres_land_on_rendered_tags_and_disparity(seq):
    """Written calibration + GT pose project each tag centre onto its rendered image within 0.5 px;
    in the right image it sits fx * baseline / depth to the left on the same row."""
    path, src, gen = seq
    cal = src.calibration
    checked = 0
    for i in (0, N_FRAMES // 2, N_FRAMES - 1):
        frame = src.frame(i)
        for tag, z, uv, half in _tag_observations(path, src, gen, i):
            r = half + 0.5 * cal.fx * gen.scene.tag_border / z  # white square + half the black frame
            cl = _white_centroid(frame.left, uv, r)
            assert np.linalg.norm(cl - uv) < 0.5, (i, tag.center, cl, uv)
            uv_r = uv - np.array([cal.bf / z, 0.0])
            cr = _white_centroid(frame.right, uv_r, r)
            assert np.linalg.norm(cr - uv_r) < 0.5, (i, tag.center, cr, uv_r)
            disparity = cl[0] - cr[0]
            assert abs(disparity * z - cal.bf) / cal.bf < 0.03
            assert abs(cl[1] - cr[1]) < 0.3
            checked += 1
    assert checked >= 4, "expected the row-end tags in view"


def test_left_right_consistency_on_orb_matches(seq):
    path, src, gen = seq
    cal = src.calibration
    frame = src.frame(3)
    depth = _depth_png(path, src, 3)
    orb = cv2.ORB_create(1500)
    kl, dl = orb.detectAndCompute(frame.left, None)
    kr, dr = orb.detectAndCompute(frame.right, None)
    assert len(kl) > 500, "textures should give plenty of ORB corners"
    matches = [m for m in cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(dl, dr) if m.distance < 40]
    pl = np.array([kl[m.queryIdx].pt for m in matches])
    pr = np.array([kr[m.trainIdx].pt for m in matches])
    z = depth[np.round(pl[:, 1]).astype(int), np.round(pl[:, 0]).astype(int)]
    ok = z > 0
    assert ok.sum() > 100
    err = (pl[ok, 0] - pr[ok, 0]) - cal.bf / z[ok]
    assert np.median(np.abs(err)) < 0.5
    assert np.median(np.abs(pl[ok, 1] - pr[ok, 1])) < 0.3


def test_euroc_source_reads_generated_sequence(seq):
    path, src, gen = seq
    assert len(src) == N_FRAMES
    assert src.calibration == gen.calibration
    assert src.rate_hz == pytest.approx(20.0)
    np.testing.assert_allclose(src.timestamps, gen.track.stamps, atol=1e-9)
    gt = src.ground_truth
    assert len(gt) == N_FRAMES and gt.meta["frame_indices"] == list(range(N_FRAMES))
    np.testing.assert_allclose(gt.poses, gen.track.poses, atol=1e-9)
    f = src.frame(N_FRAMES - 1)
    assert f.left.shape == (480, 752) and f.left.dtype == np.uint8
    assert (path / "mav0" / "cam0" / "sensor.yaml").read_text().startswith("%YAML:1.0")
    # Cached: a second call with the same parameters does not touch the images.
    img = src.left_paths[0]
    mtime = img.stat().st_mtime_ns
    assert generate_sequence("day-loop", path, n_frames=N_FRAMES, seed=SEED, workers=1, **OPTS) == path
    assert img.stat().st_mtime_ns == mtime


def test_two_callers_of_one_sequence_render_it_once(tmp_path):
    """A second caller waits for the first (folder lock) and reuses its frames; without the lock
    it took the half-written folder for a stale one, deleted it and rendered again."""
    from concurrent.futures import ThreadPoolExecutor

    out = tmp_path / "shared"
    with ThreadPoolExecutor(2) as pool:
        jobs = [pool.submit(generate_sequence, "day-loop", out, n_frames=4, seed=SEED, workers=1, **OPTS)
                for _ in range(2)]
        paths = [j.result() for j in jobs]
    assert paths == [out, out]
    src = open_source("euroc", out)
    left = sorted((out / "mav0" / "cam0" / "data").iterdir())
    assert len(src) == 4 and len(left) == 4
    # rendered once: every frame was written before the first caller returned, none after
    stamp_time = (out / "params.json").stat().st_mtime_ns
    assert all(p.stat().st_mtime_ns <= stamp_time for p in left)


def test_deterministic_from_seed(seq):
    path, src, gen = seq
    again = SequenceGenerator(resolve_params("day-loop", N_FRAMES, **OPTS), SEED)
    left, right, _ = again.stereo(2)
    np.testing.assert_array_equal(left, src.frame(2).left)
    np.testing.assert_array_equal(right, src.frame(2).right)
    other = SequenceGenerator(resolve_params("day-loop", N_FRAMES, **OPTS), SEED + 1)
    assert not np.array_equal(other.stereo(2)[0], left)


def test_loop_trajectory_revisits_start():
    params = resolve_params("day-loop")
    scene = OrchardScene(Layout(), seed=0)
    spec = path_for(scene)
    n = 1000
    track = make_track(scene, n, 20.0, speed=params.speed, seed=0)
    p = track.poses[:, :3, 3]
    assert track.arc_length[-1] > spec.perimeter  # drove a full lap
    # Back past the start: some late frame is within 0.3 m of frame 40's position, same heading.
    late = np.linalg.norm(p[600:] - p[40], axis=1)
    k = 600 + int(np.argmin(late))
    assert late.min() < 0.3
    assert track.poses[k, :3, 2] @ track.poses[40, :3, 2] > 0.99
    # Smooth: no jumps between frames, speed below 2 m/s.
    step = np.linalg.norm(np.diff(p, axis=0), axis=1)
    assert step.max() < 2.0 / 20 and np.abs(np.diff(step)).max() < 0.01
    R = track.poses[:, :3, :3]
    np.testing.assert_allclose(R @ R.transpose(0, 2, 1), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)


def test_haze_and_light_follow_the_model():
    params = resolve_params("haze-row", n_frames=2, noise=False, shade_strength=0.0)
    gen = SequenceGenerator(params, 0)
    cond = Conditions(gen.calibration, gen.scene, 0)
    h, w = 480, 752
    J = np.full((h, w), 0.4, np.float32)
    depth = np.full((h, w), 10.0, np.float32)
    label = np.full((h, w), GROUND, np.uint8)
    label[0] = SKY
    depth[0] = np.inf
    zeros = np.zeros((h, w), np.float32)
    out = RenderOutput(J, depth, label, zeros, zeros)
    img = cond.apply(out, np.random.default_rng(0), light=0.5, haze_beta=0.1, airlight=0.8,
                     shade_strength=0.0, gain=1.0, noise=False, full_well=1e4, read_noise_e=0.0,
                     low_texture_contrast=1.0)
    r = cond.ray_length[240, 375]
    t = np.exp(-0.1 * 10.0 * r)
    assert img[240, 375] == round(255 * 0.5 * (0.4 * t + 0.8 * (1 - t)))
    assert img[0, 10] == round(255 * 0.5 * 0.8)  # sky = airlight
    # Light schedule of dusk-loop fades from 0.85 to 0.1.
    dusk = SequenceGenerator(resolve_params("dusk-loop", n_frames=50), 0)
    assert dusk.light[0] == pytest.approx(0.85) and dusk.light[-1] == pytest.approx(0.1)
    assert np.all(np.diff(dusk.light) <= 1e-12)


def test_presets_known_and_kitti_rig():
    assert set(PRESETS) == {"day-loop", "dusk-loop", "haze-row", "dark-rows"}
    for name in PRESETS:
        resolve_params(name)
    cal = resolve_params("day-loop", camera="kitti").calibration
    assert (cal.width, cal.height, cal.baseline) == (1241, 376, 0.537)


@pytest.mark.parametrize("kwargs, words", [
    (dict(preset="night-owl"), "unknown preset"),
    (dict(preset="day-loop", n_frames=-5), "n_frames"),
    (dict(preset="day-loop", length_m=-1.0), "length"),
    (dict(preset="haze-row", haze_beta=-0.1), "haze density"),
    (dict(preset="day-loop", haze_betta=0.1), "unknown parameter"),
    (dict(preset="day-loop", camera="gopro"), "camera rig"),
])
def test_bad_parameters_give_clear_errors(tmp_path, kwargs, words):
    with pytest.raises(ConfigError, match=words):
        generate_sequence(out_dir=tmp_path / "x", **kwargs)
    assert not (tmp_path / "x").exists()  # nothing written


def test_refuses_to_overwrite_foreign_folder(tmp_path):
    (tmp_path / "notes.txt").write_text("mine")
    with pytest.raises(InputError, match="refusing"):
        generate_sequence("day-loop", tmp_path, n_frames=2)


def test_cli_errors_are_one_line(tmp_path):
    for args, words in ((["--preset", "day-loop", "--length", "-3"], "length"),
                        (["--preset", "fog", "--frames", "2"], "unknown preset"),
                        (["--preset", "haze-row", "--haze-beta", "-1", "--frames", "2"], "haze density")):
        r = subprocess.run([sys.executable, str(REPO / "tools" / "make_sequence.py"), *args,
                            "--out", str(tmp_path / "o")], capture_output=True, text=True, timeout=60)
        assert r.returncode == 2, r.stderr
        assert words in r.stderr and "Traceback" not in r.stderr
