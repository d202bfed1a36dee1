"""Three-point rigid RANSAC of loop verification (canopy.loop.rigid_ransac) and the vectorised
inverted index of the keyframe database, on generated data with exact answers."""
from __future__ import annotations

import numpy as np
import pytest

from canopy.loop.database import InvertedIndex, KeyframeDatabase, l1_score
from canopy.loop.rigid_ransac import rigid_ransac, triad_batched

K = np.array([[450.0, 0, 370], [0, 450.0, 240], [0, 0, 1]])


def _rotation(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    Kx = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * Kx + (1 - np.cos(angle)) * Kx @ Kx


def test_minimal_solver_is_exact_on_noise_free_triples():
    rng = np.random.default_rng(3)
    A = rng.normal(size=(20, 3, 3))
    R0, t0 = _rotation([0.3, 1, 0.2], 0.7), np.array([0.5, -1.0, 2.0])
    B = A @ R0.T + t0
    R, t = triad_batched(A, B)
    assert np.abs(R - R0).max() < 1e-9 and np.abs(t - t0).max() < 1e-9
    assert np.allclose(np.linalg.det(R), 1.0)


def _scene(rng, n, outlier_share, depth_share=1.0):
    """Candidate-camera points, the query camera moved by a known pose, matches with a share of
    wrong ones (random 3D point and pixel), some query points without stereo depth."""
    R0, t0 = _rotation([0.1, 1, 0.05], 0.25), np.array([0.4, 0.05, -0.8])
    X_c = np.c_[rng.uniform(-4, 4, n), rng.uniform(-2, 2, n), rng.uniform(3, 15, n)]
    X_q = X_c @ R0.T + t0
    uv = X_q[:, :2] / X_q[:, 2:] * K[0, 0] + K[:2, 2] + rng.normal(0, 0.5, (n, 2))
    bad = rng.random(n) < outlier_share
    X_q[bad] = np.c_[rng.uniform(-4, 4, bad.sum()), rng.uniform(-2, 2, bad.sum()), rng.uniform(3, 15, bad.sum())]
    uv[bad] = rng.uniform([0, 0], [740, 480], (bad.sum(), 2))
    X_q[rng.random(n) > depth_share] = np.nan
    T0 = np.eye(4)
    T0[:3, :3], T0[:3, 3] = R0, t0
    return X_c, X_q, uv, T0, ~bad


@pytest.mark.parametrize("outliers, depth_share", [(0.5, 1.0), (0.8, 1.0), (0.6, 0.5)])
def test_rigid_ransac_recovers_the_pose_among_wrong_matches(outliers, depth_share):
    X_c, X_q, uv, T0, good = _scene(np.random.default_rng(7), 200, outliers, depth_share)
    T, mask = rigid_ransac(X_c, X_q, uv, K, 3.0, 300, 0.999, seed=1)
    assert T is not None
    assert np.abs(T[:3, 3] - T0[:3, 3]).max() < 0.02
    angle = np.degrees(np.arccos(np.clip((np.trace(T[:3, :3].T @ T0[:3, :3]) - 1) / 2, -1, 1)))
    assert angle < 0.2
    # the consensus is the true matches (a wrong match may land within 3 px by chance)
    assert mask[good].mean() > 0.95 and (mask & ~good).sum() <= 2


def test_rigid_ransac_finds_nothing_in_random_matches_or_without_query_depth():
    rng = np.random.default_rng(11)
    X_c, X_q, uv, _, _ = _scene(rng, 60, 1.0)
    _, mask = rigid_ransac(X_c, X_q, uv, K, 3.0, 300, 0.999, seed=2)
    assert mask.sum() < 5
    T, mask = rigid_ransac(X_c, np.full_like(X_q, np.nan), uv, K, 3.0, 300, 0.999, seed=2)
    assert T is None and not mask.any()


def test_inverted_index_scores_equal_pairwise_l1_scores_across_merges_and_removals():
    rng = np.random.default_rng(5)
    InvertedIndex.MIN_MERGE, saved = 300, InvertedIndex.MIN_MERGE   # several merges with few keyframes
    try:
        db = KeyframeDatabase()
        bows = {}
        for kf in range(40):
            words = rng.choice(500, size=rng.integers(20, 60), replace=False)
            w = rng.random(len(words))
            bows[kf] = dict(zip(words.tolist(), (w / w.sum()).tolist()))
            db.add(kf, bows[kf])
        for kf in (3, 17, 39):
            db.remove(kf)
            del bows[kf]
        db.add(40, bows.setdefault(40, {1: 0.5, 2: 0.5}))
        q = bows[10]
        got = db.scores(q)
        want = {k: l1_score(q, b) for k, b in bows.items() if set(b) & set(q)}
        assert set(got) == set(want)
        assert all(abs(got[k][0] - want[k]) < 1e-12 for k in want)
        assert all(got[k][1] == len(set(bows[k]) & set(q)) for k in want)
    finally:
        InvertedIndex.MIN_MERGE = saved
