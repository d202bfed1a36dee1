"""Keyframe culling and the bounds of local mapping's cost on a still camera (canopy.backend.keyframe_culling,
canopy.backend.still_window: mapping.keyframe_culling, window_max_fixed, descriptor_max_observations)."""
from __future__ import annotations

import numpy as np
import pytest

from canopy.backend import LocalMapper, MappingParams
from canopy.backend.keyframe_culling import redundant_fraction
from canopy.backend.still_window import bounded_fixed, depth_constrained, descriptor_observations
from canopy.frontend.geometry import se3_exp
from canopy.loop.correction import apply_loop_correction
from shared.errors import ConfigError
from tests.test_backend import CALIB, keyframe, scene


def _still_run(params, n_kf=10, seed=0):
    rng = np.random.default_rng(seed)
    moving, X = scene(rng)
    still = [moving[0] @ se3_exp(np.r_[1e-5 * rng.standard_normal(3), 3e-4 * rng.standard_normal(3)])
             for _ in range(n_kf)]
    n = len(X)
    ids = np.arange(n, dtype=np.int64)
    mapper = LocalMapper(CALIB, params)
    for k, T in enumerate(still):
        existing, new = (np.full(n, -1, np.int64), ids) if k == 0 else (ids, np.full(n, -1, np.int64))
        mapper.insert_keyframe(keyframe(k, T, T, X, existing, new, rng))
    return mapper, still


def _consistent(mapper):
    for lid, lm in mapper.landmarks.items():
        for k, i in lm.obs.items():
            assert k in mapper.keyframes and mapper.keyframes[k].landmark[i] == lid
    for k, rec in mapper.keyframes.items():
        for lid in rec.landmark[rec.landmark >= 0].tolist():
            assert k in mapper.landmarks[lid].obs


def test_still_keyframes_are_culled_and_their_poses_stay_available():
    mapper, still = _still_run(MappingParams(keyframe_culling=True))
    off, _ = _still_run(MappingParams())
    assert off.n_keyframes_culled == 0 and len(off.keyframes) == 10
    # every keyframe sees every landmark: once three others see them, a keyframe is redundant
    assert mapper.n_keyframes_culled >= 5
    assert 0 in mapper.keyframes and 9 in mapper.keyframes    # the gauge and the newest stay
    assert len(mapper.keyframes) + len(mapper.culled_keyframes) == 10
    _consistent(mapper)
    poses = mapper.keyframe_poses()
    assert sorted(poses) == list(range(10))                   # culled ones through their parents
    for k in mapper.culled_keyframes:
        assert np.allclose(poses[k][:3, 3], still[k][:3, 3], atol=1e-3)
    traj = mapper.keyframe_trajectory()
    assert traj.meta["indices"] == list(range(10))
    assert np.allclose(traj.stamps, 0.1 * np.arange(10))


def test_a_culled_keyframe_follows_its_parent_through_a_correction():
    mapper, _ = _still_run(MappingParams(keyframe_culling=True))
    k = min(mapper.culled_keyframes)
    before = mapper.keyframe_poses()[k]
    C = se3_exp(np.array([0.0, 0.0, 0.1, 0.5, 0.0, 0.0]))    # a loop correction moving the whole map
    apply_loop_correction(mapper, {0: C})
    assert np.allclose(mapper.keyframe_poses()[k], C @ before, atol=1e-9)


def test_redundancy_needs_observers_at_the_same_or_a_finer_scale():
    mapper, _ = _still_run(MappingParams(), n_kf=5)
    assert redundant_fraction(mapper, 2, 3) == pytest.approx(1.0)
    for k in (0, 1, 3, 4):
        mapper.keyframes[k].octave[:] = 3                     # the others see the points two levels coarser
    assert redundant_fraction(mapper, 2, 3) == 0.0
    mapper.keyframes[2].octave[:] = 2                         # one level finer than theirs is enough
    assert redundant_fraction(mapper, 2, 3) == pytest.approx(1.0)
    assert redundant_fraction(mapper, 2, 5) == 0.0            # only four other keyframes


def test_bounds_of_the_fixed_set_and_the_descriptor_observations():
    mapper, _ = _still_run(MappingParams(window_max_fixed=3), n_kf=8)
    fixed = [0, 1, 2, 3, 4, 5]
    kept = bounded_fixed(mapper, mapper.keyframes[7], [7, 6], fixed)
    assert 0 in kept and len(kept) <= 4                       # the gauge kept beside the best 3
    unbounded, _ = _still_run(MappingParams(), n_kf=8)
    assert bounded_fixed(unbounded, unbounded.keyframes[7], [7, 6], fixed) == fixed
    obs = {k: 10 + k for k in range(12)}
    assert descriptor_observations(obs, 4) == {8: 18, 9: 19, 10: 20, 11: 21}
    assert descriptor_observations(obs, 0) is obs


def test_ba_moves_only_landmarks_with_a_stereo_observation():
    mapper, _ = _still_run(MappingParams(window_max_fixed=3), n_kf=3)
    lm_ids = [0, 1, 2]
    e_kf = np.array([1, 2, 1, 2, 2])
    e_lm = np.array([0, 0, 1, 1, 2])
    e_kp = np.array([0, 0, 1, 1, 2])
    mapper.keyframes[1].u_right[1] = -1.0                     # landmark 1: left-image observations only
    mapper.keyframes[2].u_right[1] = -1.0
    ids, kf, lm, kp = depth_constrained(mapper, lm_ids, e_kf, e_lm, e_kp)
    assert ids == [0, 2]
    assert lm.tolist() == [0, 0, 2] and kf.tolist() == [1, 2, 2] and kp.tolist() == [0, 0, 2]


def test_options_are_validated():
    for bad in (dict(keyframe_culling_redundancy=0.0), dict(keyframe_culling_observers=0),
                dict(keyframe_culling_keep_recent=-1), dict(window_max_fixed=-1), dict(descriptor_max_observations=2)):
        with pytest.raises(ConfigError, match=next(iter(bad))):
            MappingParams(**bad).validate()
