"""New landmarks triangulated across keyframes in the stereo local mapper
(mapping.triangulate_new_points, canopy.backend.triangulation) on generated scenes with exact
poses: the points land on the true 3-D points, the fast pair matcher agrees with the monocular
mapper's dense one, and the option off leaves the map as before."""
from __future__ import annotations

import numpy as np
import pytest

from canopy.backend import LocalMapper, MappingParams
from canopy.backend.triangulation import check_tracker_ids, match_pair, pair_gates
from canopy.frontend import KeyframeData
from canopy.frontend.geometry import project_stereo, se3_exp, se3_inv
from canopy.mono.triangulation import new_points_between
from shared.errors import ConfigError
from shared.types import StereoCalibration

CALIB = StereoCalibration(fx=700.0, fy=700.0, cx=600.0, cy=180.0, baseline=0.54, width=1200, height=360)


def _scene(rng, n_stereo=300, n_far=200):
    """Near points (stereo landmarks) and far ones (no stereo match: only triangulation finds them)."""
    near = np.stack([rng.uniform(-8, 8, n_stereo), rng.uniform(-2, 2, n_stereo), rng.uniform(5, 20, n_stereo)], 1)
    far = np.stack([rng.uniform(-30, 30, n_far), rng.uniform(-4, 4, n_far), rng.uniform(20, 60, n_far)], 1)
    return near, far


def _keyframe(k, T, X, desc, ids_seen, ids_new, depth, rng, pixel_noise):
    meas, _ = project_stereo(se3_inv(T), X, CALIB)
    uv = meas[:, :2] + pixel_noise * rng.standard_normal((len(X), 2))
    u_right = np.where(depth > 0, meas[:, 2], -1.0)
    return KeyframeData(index=k, timestamp=0.1 * k, T_world_cam=T, uv=uv.astype(np.float32),
                        u_right=u_right.astype(np.float32), depth=depth.astype(np.float32),
                        descriptors=desc, octave=np.zeros(len(X), np.int32),
                        landmark_ids=ids_seen, new_landmark_ids=ids_new, restart=(k == 0))


def _run(params: MappingParams, poses, rng, pixel_noise=0.2):
    """Keyframes along ``poses`` seeing the scene: the near points are stereo landmarks made by
    the first keyframe and re-observed, the far points have no stereo match anywhere."""
    near, far = _scene(rng)
    X = np.concatenate([near, far])
    n_near = len(near)
    desc = rng.integers(0, 256, (len(X), 32), dtype=np.uint8)
    mapper = LocalMapper(CALIB, params)
    ids = np.arange(len(X), dtype=np.int64)
    is_near = ids < n_near
    for k, T in enumerate(poses):
        depth = np.where(is_near, (se3_inv(T)[:3, :3] @ X.T).T[:, 2] + se3_inv(T)[2, 3], 0.0)
        seen = np.where(is_near & (k > 0), ids, -1)
        new = np.where(is_near & (k == 0), ids, -1)
        mapper.insert_keyframe(_keyframe(k, T, X, desc, seen, new, depth, rng, pixel_noise))
    return mapper, X, n_near


def _forward_poses(n=3, step=1.5):
    return [se3_exp(np.array([0.0, 0.01 * k, 0.0, 0.1 * k, 0.0, step * k])) for k in range(n)]


def test_triangulated_points_land_on_the_true_points():
    rng = np.random.default_rng(3)
    params = MappingParams(triangulate_new_points=True, ba_iterations=5)
    mapper, X, n_near = _run(params, _forward_poses(), rng)
    base = params.triangulate_id_base
    tri = {lid: lm for lid, lm in mapper.landmarks.items() if lid >= base}
    assert mapper.n_triangulated >= 100   # of the 200 far points (some lack parallax)
    assert len(tri) >= 100
    err, depth = [], []
    for lm in tri.values():
        k, row = next(iter(lm.obs.items()))
        assert row >= n_near           # only keypoints without a landmark are triangulated
        true = X[row]
        err.append(np.linalg.norm(lm.position - true))
        depth.append(np.linalg.norm(true - mapper.keyframes[k].T_world_cam[:3, 3]))
    rel = np.array(err) / np.array(depth)
    # 0.2 px noise over a 1.5-3 m baseline at 20-60 m: a few % of the distance at most
    assert np.median(rel) < 0.01
    assert np.percentile(rel, 95) < 0.05
    # each keypoint carries one landmark, and the store's reverse index agrees
    for lid, lm in tri.items():
        for k, row in lm.obs.items():
            assert mapper.keyframes[k].landmark[row] == lid


def test_option_off_makes_no_landmarks_beyond_the_stereo_ones():
    rng = np.random.default_rng(3)
    mapper, X, n_near = _run(MappingParams(ba_iterations=5), _forward_poses(), rng)
    assert mapper.n_triangulated == 0
    assert max(mapper.landmarks) < n_near


@pytest.mark.parametrize("motion", ["forward", "backward", "sideways"])
def test_fast_pair_matcher_agrees_with_the_dense_one(motion):
    """``match_pair`` (angle-sorted candidates around the epipole, or parallel lines) finds the
    matches of the monocular mapper's dense band mask + brute-force matcher."""
    rng = np.random.default_rng(5)
    step = {"forward": [0.0, 0.0, 2.0], "backward": [0.0, 0.0, -2.0], "sideways": [2.0, 0.0, 0.0]}[motion]
    poses = [np.eye(4), se3_exp(np.array([0.0, 0.02, 0.0] + step))]
    _, far = _scene(rng, n_stereo=1, n_far=400)
    desc = rng.integers(0, 256, (len(far), 32), dtype=np.uint8)
    mapper = LocalMapper(CALIB, MappingParams())
    recs = []
    for k, T in enumerate(poses):
        none = np.full(len(far), -1, np.int64)
        mapper.insert_keyframe(_keyframe(k, T, far, desc, none, none, np.zeros(len(far)), rng, 0.2))
        recs.append(mapper.keyframes[k])
    gates = pair_gates(MappingParams())
    a, b = recs[1], recs[0]
    fast = match_pair(a, b, CALIB, gates, 1.2, 1.0)
    dense = new_points_between(a, b, CALIB, gates, 1.2, 1.0)
    assert len(fast[0]) >= 100
    assert set(zip(fast[0].tolist(), fast[1].tolist())) == set(zip(dense[0].tolist(), dense[1].tolist()))
    assert np.array_equal(fast[0], fast[1])      # the same scene point in both keyframes
    np.testing.assert_allclose(np.sort(fast[2], axis=0), np.sort(dense[2], axis=0))


def test_tracker_ids_in_the_mapper_range_are_refused():
    with pytest.raises(ValueError, match="new_landmark_ids"):
        check_tracker_ids(np.array([0, 5, 1 << 20]), 1 << 20)
    check_tracker_ids(np.array([0, (1 << 20) - 1]), 1 << 20)


def test_triangulation_params_are_validated():
    with pytest.raises(ConfigError, match="triangulate_covisible"):
        MappingParams(triangulate_covisible=0)
    with pytest.raises(ConfigError, match="triangulate_min_observations"):
        MappingParams(triangulate_min_observations=1)
