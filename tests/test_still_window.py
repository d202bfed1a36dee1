"""Local BA's window without redundant viewpoints (canopy.backend.still_window, mapping.window_min_view_change_px)."""
from __future__ import annotations

import numpy as np
import pytest

from canopy.backend import LocalMapper, MappingParams
from canopy.backend.still_window import median_depth, view_change_px
from canopy.frontend.geometry import se3_exp
from shared.errors import ConfigError
from tests.test_backend import CALIB, keyframe, scene


def test_view_change_px_adds_parallax_and_rotation():
    T = np.eye(4)
    moved = np.eye(4)
    moved[:3, 3] = [0.01, 0.0, 0.0]                        # 1 cm at 2 m with fx 450: 2.25 px
    assert view_change_px(T, moved, 2.0, 450.0) == pytest.approx(2.25)
    turned = se3_exp(np.array([0.0, 0.002, 0.0, 0.0, 0.0, 0.0]))   # 2 mrad: 0.9 px at any depth
    assert view_change_px(T, turned, 2.0, 450.0) == pytest.approx(0.9, rel=1e-6)
    assert view_change_px(T, turned, 50.0, 450.0) == pytest.approx(0.9, rel=1e-6)
    with pytest.raises(ValueError, match="depth"):
        view_change_px(T, moved, 0.0, 450.0)
    assert median_depth(np.array([0.0, -1.0, np.nan])) is None
    assert median_depth(np.array([0.0, 2.0, 4.0, 3.0])) == 3.0


def test_window_option_is_validated():
    with pytest.raises(ConfigError, match="window_min_view_change_px"):
        MappingParams(window_min_view_change_px=-1.0).validate()


def _run(poses, X, params, rng):
    n = len(X)
    ids = np.arange(n, dtype=np.int64)
    mapper = LocalMapper(CALIB, params)
    windows = []
    for k, T in enumerate(poses):
        if k == 0:
            kf = keyframe(0, T, T, X, np.full(n, -1, np.int64), ids, rng)
        else:
            kf = keyframe(k, T, T, X, ids, np.full(n, -1, np.int64), rng)
        mapper.insert_keyframe(kf)
        windows.append(mapper.last_window)
    return windows


def test_still_keyframes_stay_fixed_and_moving_ones_fill_the_window():
    rng = np.random.default_rng(3)
    moving, X = scene(rng)                 # 0.15-0.25 m between keyframes at 4-9 m: tens of pixels
    # a still rig: sub-millimetre, sub-0.1 mrad differences (well below a pixel at 4-9 m)
    still = [moving[0] @ se3_exp(np.r_[1e-5 * rng.standard_normal(3), 3e-4 * rng.standard_normal(3)])
             for _ in range(len(moving))]
    on = MappingParams(window_min_view_change_px=1.0)
    off = MappingParams()
    for local, fixed in _run(still, X, on, np.random.default_rng(0))[1:]:
        assert len(local) == 1                         # the new keyframe only: nothing else adds geometry
        assert fixed                                   # the others still constrain the landmarks
    w_on = _run(moving, X, on, np.random.default_rng(0))
    w_off = _run(moving, X, off, np.random.default_rng(0))
    assert w_on == w_off                               # a moving camera keeps ORB-SLAM's window
    assert max(len(local) for local, _ in w_off) >= 3
    assert max(len(local) for local, _ in _run(still, X, off, np.random.default_rng(0))) >= 3
