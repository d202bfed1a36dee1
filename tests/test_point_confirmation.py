"""Confirmation of triangulated landmarks before tracking gets them (mapping.triangulate_fuse /
triangulate_confirm, canopy.backend.point_confirmation) on a generated scene with exact
poses: a point seen by two keyframes only is left out of the update and culled when no third
keyframe finds it; one a third keyframe finds (the mapper's own Fuse search) is sent, at its
true position; a triangulated point that duplicates a stereo landmark is merged into it."""
from __future__ import annotations

import numpy as np
import pytest

from canopy.backend import LocalMapper, MappingParams
from canopy.backend.point_confirmation import confirmed_mask, fuse_matches
from canopy.frontend import KeyframeData
from canopy.frontend.geometry import project_stereo, se3_exp, se3_inv
from shared.errors import ConfigError
from shared.types import StereoCalibration

CALIB = StereoCalibration(fx=700.0, fy=700.0, cx=600.0, cy=180.0, baseline=0.54, width=1200, height=360)
BASE = MappingParams().triangulate_id_base


def _scene(rng, n_near=300, n_far=300):
    near = np.stack([rng.uniform(-8, 8, n_near), rng.uniform(-2, 2, n_near), rng.uniform(5, 20, n_near)], 1)
    far = np.stack([rng.uniform(-30, 30, n_far), rng.uniform(-4, 4, n_far), rng.uniform(25, 60, n_far)], 1)
    return np.concatenate([near, far]), n_near


def _poses(n):
    return [se3_exp(np.array([0.0, 0.01 * k, 0.0, 0.1 * k, 0.0, 2.5 * k])) for k in range(n)]


def _run(params, n_kf, far_desc_of_kf, rng, pixel_noise=0.2):
    """Keyframes moving forward: the near points are stereo landmarks (made by keyframe 0, then
    matched by tracking); the far points have no stereo match and tracking never matches them,
    so only triangulation and the mapper's search can make and observe them.
    ``far_desc_of_kf(k, desc)`` gives keyframe k's descriptors (to make a keyframe not see them).
    Returns the mapper, the updates, the scene and the number of near points."""
    X, n_near = _scene(rng)
    desc = rng.integers(0, 256, (len(X), 32), dtype=np.uint8)
    ids = np.arange(len(X), dtype=np.int64)
    is_near = ids < n_near
    mapper = LocalMapper(CALIB, params)
    mapper.made_by = []
    updates = []
    for k, T in enumerate(_poses(n_kf)):
        T_cw = se3_inv(T)
        meas, Pc = project_stereo(T_cw, X, CALIB)
        uv = meas[:, :2] + pixel_noise * rng.standard_normal((len(X), 2))
        # a point out of view is no keypoint: its row gets a corner and a descriptor of its own
        out = ~((Pc[:, 2] > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < CALIB.width) & (uv[:, 1] >= 0) & (uv[:, 1] < CALIB.height))
        uv[out] = 0.0
        kf_desc = far_desc_of_kf(k, desc, n_near).copy()
        kf_desc[out] = rng.integers(0, 256, (int(out.sum()), 32), dtype=np.uint8)
        depth = np.where(is_near, Pc[:, 2], 0.0)
        kf = KeyframeData(index=k, timestamp=0.1 * k, T_world_cam=T, uv=uv.astype(np.float32),
                          u_right=np.where(is_near, meas[:, 2], -1.0).astype(np.float32),
                          depth=depth.astype(np.float32), descriptors=kf_desc,
                          octave=np.zeros(len(X), np.int32),
                          landmark_ids=np.where(is_near & ~out & (k > 0), ids, -1),
                          new_landmark_ids=np.where(is_near & ~out & (k == 0), ids, -1), restart=(k == 0))
        updates.append(mapper.insert_keyframe(kf))
        mapper.made_by.append(mapper.n_triangulated)   # ids below BASE + this were made by keyframes <= k
    return mapper, updates, X, n_near


def _same(k, desc, n_near):
    return desc


def _params(**kw):
    return MappingParams(triangulate_new_points=True, triangulate_fuse=True, triangulate_confirm=True,
                         ba_iterations=5, **kw)


def test_points_seen_by_two_keyframes_are_withheld_then_confirmed_by_a_third():
    rng = np.random.default_rng(7)
    mapper, updates, X, n_near = _run(_params(), 3, _same, rng)
    # keyframe 1 triangulates the far points with keyframe 0: two observations, not for tracking
    made_at_1 = [lid for lid in mapper.landmarks if BASE <= lid < BASE + mapper.made_by[1]]
    assert not (updates[1].landmark_ids >= BASE).any()
    # keyframe 2 finds them by projection (Fuse): three observations, sent, on the true points
    assert len(made_at_1) >= 100
    sent = updates[2].landmark_ids[updates[2].landmark_ids >= BASE]
    assert len(sent) >= 100
    assert len(set(made_at_1) & set(sent.tolist())) >= 0.8 * len(made_at_1)
    rel = []
    for lid in sent.tolist():
        lm = mapper.landmarks[lid]
        assert len(lm.obs) >= 3
        rows = set(lm.obs.values())
        assert len(rows) == 1                       # the same scene point in every keyframe
        true = X[rows.pop()]
        rel.append(np.linalg.norm(lm.position - true) / np.linalg.norm(true - mapper.keyframes[0].T_world_cam[:3, 3]))
    # 0.2 px noise, 2.5-5 m baselines, 25-60 m away (points near the epipole are the worst)
    assert np.median(rel) < 0.01 and np.percentile(rel, 95) < 0.05
    # the store's reverse index agrees
    for lid in sent.tolist():
        for k, row in mapper.landmarks[lid].obs.items():
            assert mapper.keyframes[k].landmark[row] == lid


def test_points_no_third_keyframe_finds_are_never_sent_and_culled():
    rng = np.random.default_rng(7)
    scramble = np.random.default_rng(11)

    def hidden_after_1(k, desc, n_near):   # keyframes 2, 3 see other descriptors at the far points
        if k < 2:
            return desc
        out = desc.copy()
        out[n_near:] = scramble.integers(0, 256, (len(desc) - n_near, 32), dtype=np.uint8)
        return out

    mapper, updates, X, n_near = _run(_params(), 4, hidden_after_1, rng)
    made_at_1 = set(range(BASE, BASE + mapper.made_by[1]))
    assert len(made_at_1) >= 100
    assert not any(made_at_1 & set(u.landmark_ids.tolist()) for u in updates)
    assert not made_at_1 & set(mapper.landmarks)   # culled: fewer than 3 keyframes by age 2


def test_without_confirmation_tracking_gets_them_at_once():
    rng = np.random.default_rng(7)
    mapper, updates, X, n_near = _run(MappingParams(triangulate_new_points=True, ba_iterations=5), 2, _same, rng)
    assert (updates[1].landmark_ids >= BASE).sum() >= 100


def test_unconfirmed_points_can_be_kept_out_of_local_ba():
    """triangulate_confirm_ba=False: BA sees confirmed points only, so two-view points keep their
    triangulated positions through keyframe 1's BA (with BA they move)."""
    moved = {}
    for ba in (True, False):
        rng = np.random.default_rng(7)
        mapper, updates, X, n_near = _run(_params(triangulate_confirm_ba=ba), 2, _same, rng)
        tri = np.array(sorted(lid for lid in mapper.landmarks if lid >= BASE))
        moved[ba] = tri, mapper.landmarks.rows.pos[tri].copy()
        assert len(tri) >= 100
        # the keyframe rows were restored after BA
        for lid in tri.tolist():
            for k, row in mapper.landmarks[lid].obs.items():
                assert mapper.keyframes[k].landmark[row] == lid
    assert np.array_equal(moved[True][0], moved[False][0])
    assert not np.allclose(moved[True][1], moved[False][1])


@pytest.mark.parametrize("merge", [True, False])
def test_a_point_duplicating_a_stereo_landmark_is_merged_into_it(merge):
    """With triangulate_fuse_merge the duplicate's observations move to the stereo landmark;
    without, the duplicate only leaves the map."""
    rng = np.random.default_rng(7)
    mapper, _, X, n_near = _run(_params(triangulate_fuse_merge=merge), 2, _same, rng)
    lid = min(i for i in mapper.landmarks if i >= BASE)
    lm = mapper.landmarks[lid]
    kf1 = mapper.keyframes[1]
    row = lm.obs[1]
    # pretend keyframe 1's keypoint of that point had a stereo landmark of its own: the fuse of
    # a third keyframe that has it must merge, not duplicate
    from canopy.backend.point_confirmation import fuse_into
    stereo_id = 0
    kf0 = mapper.keyframes[0]
    stereo = mapper.landmarks[stereo_id]
    mapper._remove_observation(stereo_id, 1)
    kf0.landmark[stereo.obs[0]] = -1   # move stereo landmark 0's keyframe-0 observation to the point's row there
    row0 = lm.obs[0]
    lm.obs.pop(0)
    stereo.obs[0] = row0
    kf0.landmark[row0] = stereo_id
    added, merged = fuse_into(mapper, kf0, np.array([lid]), 1.2)
    assert (added, merged) == (0, 1)
    assert lid not in mapper.landmarks
    if merge:
        assert stereo.obs[1] == row and kf1.landmark[row] == stereo_id
    else:
        assert 1 not in stereo.obs and kf1.landmark[row] == -1


def test_fuse_matches_respects_the_window_and_descriptors():
    rng = np.random.default_rng(2)
    X, _ = _scene(rng, n_near=50, n_far=50)
    T = _poses(2)[1]
    meas, _ = project_stereo(se3_inv(T), X, CALIB)
    desc = rng.integers(0, 256, (len(X), 32), dtype=np.uint8)

    class Rec:
        T_world_cam, uv, octave, descriptors = T, meas[:, :2] + 1.0, np.zeros(len(X), np.int64), desc

    ref = np.zeros((len(X), 3))
    q, r = fuse_matches(Rec, X, desc, ref, CALIB, 1.2, 5.991, 1.0, 50)
    inside = (meas[:, 0] >= 0) & (meas[:, 0] < CALIB.width) & (meas[:, 1] >= 0) & (meas[:, 1] < CALIB.height)
    assert set(q.tolist()) == set(np.flatnonzero(inside).tolist()) and np.array_equal(q, r)
    Rec.uv = meas[:, :2] + 3.0                                     # 4.2 px off: outside the 2.45 px window
    assert len(fuse_matches(Rec, X, desc, ref, CALIB, 1.2, 5.991, 1.0, 50)[0]) == 0
    Rec.uv = meas[:, :2]
    Rec.descriptors = rng.integers(0, 256, (len(X), 32), dtype=np.uint8)   # other descriptors
    assert len(fuse_matches(Rec, X, desc, ref, CALIB, 1.2, 5.991, 1.0, 50)[0]) == 0
    Rec.descriptors = desc
    far_side = X + 1000.0 * (X - T[:3, 3])                          # seen from the opposite side
    assert len(fuse_matches(Rec, X, desc, far_side, CALIB, 1.2, 5.991, 1.0, 50)[0]) == 0


def test_confirmed_mask_and_params():
    class Lm:
        def __init__(self, n):
            self.obs = dict.fromkeys(range(n), 0)

    lms = {3: Lm(1), BASE: Lm(2), BASE + 1: Lm(3)}
    assert confirmed_mask(np.array([3, BASE, BASE + 1]), lms, BASE, 3).tolist() == [True, False, True]
    with pytest.raises(ConfigError, match="triangulate_fuse_neighbours"):
        MappingParams(triangulate_fuse_neighbours=-1)
