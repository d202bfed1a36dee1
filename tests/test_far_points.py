"""Far stereo points as bearing-only measurements (tracking.stereo_obs_max_depth_baselines) and
ORB-SLAM's frustum test of the local-map search (tracking.view_max_angle_deg), on a rendered
textured wall with exact ground truth."""
import numpy as np

from canopy.backend import LocalMapper
from canopy.frontend import Tracker, TrackingParams
from canopy.frontend.geometry import rotation_angle, se3_exp, se3_inv
from shared.types import StereoFrame
from tests.test_frontend import CALIB, render_wall, textured_image


def _track_wall(params: TrackingParams, n: int = 8):
    rng = np.random.default_rng(8)
    texture = textured_image(rng, 1600, 1600, blur=2.0)
    poses = [se3_exp(np.array([0.0, 0.01 * i, 0.0, 0.04 * i, 0.01 * i, 0.05 * i])) for i in range(n)]
    tracker = Tracker(CALIB, params)
    mapper = LocalMapper(CALIB)
    keyframes, errors = [], []
    for i, T in enumerate(poses):
        frame = StereoFrame(i, 0.05 * i, render_wall(texture, T, CALIB), render_wall(texture, T, CALIB, right=True))
        res = tracker.track(frame)
        assert res.status in ("init", "ok"), (i, res.lost_reason)
        if res.is_keyframe:
            keyframes.append(res.keyframe)
            tracker.apply_map_update(mapper.insert_keyframe(res.keyframe))
        err = se3_inv(T) @ res.T_world_cam
        errors.append((np.linalg.norm(err[:3, 3]), np.degrees(rotation_angle(err[:3, :3]))))
    return keyframes, np.array(errors), mapper


def test_points_beyond_the_stereo_depth_are_monocular_in_keyframes_and_ba():
    # the wall is ~5 m away: 30 baselines puts all of it (3.6 m) beyond the stereo measurement depth
    keyframes, errors, mapper = _track_wall(TrackingParams(stereo_obs_max_depth_baselines=30.0))
    first = keyframes[0]
    assert (first.depth > 0).sum() > 100                     # stereo depth still measured ...
    assert np.all(first.u_right[first.depth > 3.6] < 0)      # ... but no right column for far points
    assert (first.new_landmark_ids >= 0).sum() > 100          # their depth initialises landmarks
    for kf in mapper.keyframes.values():                     # BA sees monocular edges only
        assert np.all(kf.u_right[kf.landmark >= 0] < 0)
    # bearing-only measurements of landmarks placed by stereo still track the exact poses
    assert errors[:, 0].max() < 0.02 and errors[:, 1].max() < 0.15, errors


def test_frustum_test_keeps_tracking_and_rejects_landmarks_seen_from_behind():
    keyframes, errors, _ = _track_wall(TrackingParams(view_max_angle_deg=60.0))
    assert errors[:, 0].max() < 0.01 and errors[:, 1].max() < 0.1, errors
    tracker = Tracker(CALIB, TrackingParams(view_max_angle_deg=60.0))
    ids = np.arange(3)
    pos = np.array([[0.0, 0.0, 5.0], [0.0, 0.0, 5.0], [0.0, 0.0, 50.0]])
    tracker._record_viewing(ids, pos, np.zeros(3), np.zeros(3, np.int64))
    T_front, T_behind = np.eye(4), np.eye(4)
    T_behind[:3, 3] = [0.0, 0.0, 10.0]                        # looking at the points from their far side
    T_behind[:3, :3] = np.diag([-1.0, 1.0, -1.0])
    assert tracker._in_frustum(T_front, ids, pos).tolist() == [True, True, True]
    # the two points at 5 m are seen from behind; the one at 50 m from its own side, 40 m away
    assert tracker._in_frustum(T_behind, ids, pos).tolist() == [False, False, True]
    T_far = np.eye(4)
    T_far[:3, 3] = [0.0, 0.0, -100.0]                         # beyond the scale ranges (1.2 x 5 m, 1.2 x 50 m)
    assert tracker._in_frustum(T_far, ids, pos).tolist() == [False, False, False]  # 105 m, 150 m away
    unknown = np.array([10_000])                              # a loaded map's landmark: not judged
    assert tracker._in_frustum(T_behind, unknown, pos[:1]).tolist() == [True]
