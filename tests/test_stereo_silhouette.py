"""Stereo keypoints on occluding contours (canopy.frontend.stereo_silhouette, tracking.contour_*),
on a rendered two-plane scene with exact depth: a textured board 3 m away covering the left part
of the view in front of a textured wall 8 m away."""
import cv2
import numpy as np
import pytest

from canopy.backend import LocalMapper
from canopy.frontend import Tracker, TrackingParams, match_stereo
from canopy.frontend.features import OrbExtractor
from canopy.frontend.geometry import rotation_angle, se3_exp, se3_inv
from canopy.frontend.stereo_silhouette import ContourParams, SilhouetteDetector
from shared.errors import ConfigError
from shared.types import StereoFrame
from tests.test_frontend import CALIB, camera_rays, textured_image

# In this clean scene the stereo SAD outlier test alone rejects every rim point (a window across a
# bright-dark step matches badly); in the orchard's crowns many pass it (docs/notes/s4-drift.md).
# It is switched off here so that rim points reach the contour test and tracking.
NO_SAD = dict(sad_outlier_factor=100.0, sad_outlier_factor_noisy=100.0)
BOARD_Z, WALL_Z, BOARD_EDGE_X = 3.0, 8.0, 0.3  # board: world x < BOARD_EDGE_X (+ teeth) on z = 3 m
TOOTH = 0.1  # m: the rim has square teeth (corners ORB finds, as on a crown's outline)


def render_board_scene(tex_board, tex_wall, T_wc, calib, right=False):
    """Image and exact depth (m, along the optical axis) of the board-in-front-of-wall scene."""
    o, d = camera_rays(T_wc, calib, right)

    def hit(z, tex, extent):
        s = (z - o[2]) / d[..., 2]
        P = o + s[..., None] * d
        h, w = tex.shape
        mx = ((P[..., 0] + extent) / (2 * extent) * (w - 1)).astype(np.float32)
        my = ((P[..., 1] + extent) / (2 * extent) * (h - 1)).astype(np.float32)
        return s, P, cv2.remap(tex, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)

    s_b, P_b, img_b = hit(BOARD_Z, tex_board, 4.0)
    s_w, _, img_w = hit(WALL_Z, tex_wall, 10.0)
    teeth = TOOTH * (np.sin(P_b[..., 1] * np.pi / 0.25) > 0)  # 0.25 m tall teeth
    on_board = P_b[..., 0] < BOARD_EDGE_X + teeth
    img = np.where(on_board, img_b // 2 + 128, img_w // 2)  # a bright board before a dark wall
    depth = np.where(on_board, s_b, s_w)  # rays have unit z in the camera: s is the depth
    return img, depth


def _scene(T_wc=np.eye(4)):
    rng = np.random.default_rng(3)
    tex_b, tex_w = textured_image(rng, 1200, 1200, blur=2.0), textured_image(rng, 1600, 1600, blur=2.0)
    left, depth = render_board_scene(tex_b, tex_w, T_wc, CALIB)
    right, _ = render_board_scene(tex_b, tex_w, T_wc, CALIB, right=True)
    return (tex_b, tex_w), left, right, depth


def _true_contour(depth, uv, window_px=3):
    """Ground truth: exact disparity varies by > 10 % within the window of the keypoint."""
    disp = (CALIB.bf / depth).astype(np.float32)
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * window_px + 1, 2 * window_px + 1))
    hi, lo = cv2.dilate(disp, k), cv2.erode(disp, k)
    x, y = np.round(uv[:, 0]).astype(int), np.round(uv[:, 1]).astype(int)
    return hi[y, x] > 1.1 * lo[y, x]


def test_point_on_the_depth_edge_is_flagged_and_points_on_flat_surfaces_are_not():
    _, left, right, depth = _scene()
    det = SilhouetteDetector(ContourParams())
    # rows where the rim is at BOARD_EDGE_X, mid-way between teeth (teeth: world y in (0, 0.25) + k 0.5)
    rows = CALIB.cy + CALIB.fy * (np.array([-1.125, -0.625, -0.125, 0.375, 0.875]) / BOARD_Z)
    edge_u = CALIB.cx + CALIB.fx * BOARD_EDGE_X / BOARD_Z  # the board's rim in the left image
    on_edge = np.stack([np.full(len(rows), edge_u), rows], axis=1)
    board = np.stack([np.full(len(rows), edge_u - 60), rows], axis=1)   # 60 px inside the board
    wall = np.stack([np.full(len(rows), edge_u + 60), rows], axis=1)    # 60 px out on the wall
    uv = np.concatenate([on_edge, board, wall])
    truth = _true_contour(depth, uv)
    assert truth.tolist() == [True] * len(rows) + [False] * (2 * len(rows))  # the scene is what we think
    flags = det(left, right, uv)
    assert flags[:len(rows)].all(), flags
    assert not flags[len(rows):].any(), flags


def test_flags_of_orb_stereo_points_agree_with_the_exact_depth():
    _, left, right, depth = _scene()
    p = TrackingParams(**NO_SAD)
    lf, rf = OrbExtractor(p).extract(left), OrbExtractor(p).extract(right)
    stereo = match_stereo(lf, rf, left, right, CALIB, p)
    idx = np.flatnonzero(stereo.valid)
    uv = lf.uv[idx].astype(np.float64)
    flags = SilhouetteDetector(ContourParams())(left, right, uv)
    truth = _true_contour(depth, uv)
    assert truth.sum() >= 5 and (~truth).sum() >= 100
    assert flags[truth].mean() >= 0.8                     # the rim's points are found ...
    assert flags[~truth].mean() <= 0.1                    # ... and flat surfaces are left alone
    # the points it flags are the ones whose stereo depth is wrong: the SAD window straddles the rim
    z_err = np.abs(stereo.depth[idx] / depth[np.round(uv[:, 1]).astype(int), np.round(uv[:, 0]).astype(int)] - 1)
    assert np.median(z_err[~flags]) < 0.02


def test_bad_contour_settings_are_named():
    with pytest.raises(ConfigError, match="contour_ratio"):
        TrackingParams(contour_ratio=0.0)
    with pytest.raises(ConfigError, match="contour_downscale"):
        TrackingParams(contour_downscale=3)
    with pytest.raises(ValueError, match="left image"):
        SilhouetteDetector(ContourParams())(np.zeros((10, 12), np.uint8), np.zeros((10, 11), np.uint8),
                                            np.zeros((1, 2)))


def _noisy(img, sigma, seed):
    """The image under strong sensor noise (a dark frame after enhancement: sigma ~25 grey levels)."""
    rng = np.random.default_rng(seed)
    return np.clip(img.astype(np.float32) + rng.normal(0.0, sigma, img.shape), 0, 255).astype(np.uint8)


def test_frame_gate_leaves_frames_alone_where_block_matching_fails():
    # on noise block matching rejects much of the image, and "unmatched = background" then flags
    # points on flat surfaces; the gate (min_matched_fraction) flags nothing on such a frame and
    # changes nothing on the clean one
    _, left, right, _ = _scene()
    edge_u = CALIB.cx + CALIB.fx * BOARD_EDGE_X / BOARD_Z
    rows = np.linspace(60, 420, 30)
    uv = np.concatenate([np.stack([np.full(len(rows), edge_u - 60), rows], 1),     # board
                         np.stack([np.full(len(rows), edge_u + 60), rows], 1)])    # wall
    det, gated = SilhouetteDetector(ContourParams()), SilhouetteDetector(ContourParams(min_matched_fraction=0.6))
    d, first = det.disparity(left, right)
    assert det.matched_fraction(d, first) >= 0.8
    assert (gated(left, right, uv) == det(left, right, uv)).all()
    nl, nr = _noisy(left, 60, 1), _noisy(right, 60, 2)
    d, first = det.disparity(nl, nr)
    assert det.matched_fraction(d, first) < 0.6
    assert det(nl, nr, uv).mean() > 0.3          # ungated: flat-surface points flagged
    assert not gated(nl, nr, uv).any()


def test_flagged_fraction_cap_and_unmatched_switch():
    _, left, right, _ = _scene()
    edge_u = CALIB.cx + CALIB.fx * BOARD_EDGE_X / BOARD_Z
    rows = CALIB.cy + CALIB.fy * (np.array([-1.125, -0.625, -0.125, 0.375, 0.875]) / BOARD_Z)
    on_edge = np.stack([np.full(len(rows), edge_u), rows], axis=1)
    flat = np.stack([np.full(len(rows), edge_u - 60), rows], axis=1)
    det = SilhouetteDetector(ContourParams())
    assert det(left, right, on_edge).all()
    # every tested point flagged: over a cap of 0.9 the frame's flags are not believed
    assert not SilhouetteDetector(ContourParams(max_flagged_fraction=0.9))(left, right, on_edge).any()
    uv = np.concatenate([on_edge, flat])
    assert (SilhouetteDetector(ContourParams(max_flagged_fraction=0.9))(left, right, uv) == det(left, right, uv)).all()
    # a disparity map with a hole: unmatched flags it only with unmatched_is_contour
    disp = np.full((240, 376), 20.0, np.float32)
    disp[100:140, 200:240] = 0.0
    pts = np.array([[2 * 220.0, 2 * 120.0], [2 * 300.0, 2 * 60.0]])
    assert det.flags(disp, 0, pts).tolist() == [True, False]
    no_unm = SilhouetteDetector(ContourParams(unmatched_is_contour=False))
    assert no_unm.flags(disp, 0, pts).tolist() == [False, False]
    # unmatched_min_radius: a wide hole (sky) still counts, a 2 px one (a low-texture patch) does not
    disp[58:60, 148:150] = 0.0
    pts = np.array([[2 * 220.0, 2 * 120.0], [2 * 149.0, 2 * 59.0]])
    assert det.flags(disp, 0, pts).tolist() == [True, True]
    wide = SilhouetteDetector(ContourParams(unmatched_min_radius=4))
    assert wide.flags(disp, 0, pts).tolist() == [True, False]
    with pytest.raises(ConfigError, match="contour_min_matched_fraction"):
        TrackingParams(contour_min_matched_fraction=1.5)
    with pytest.raises(ConfigError, match="contour_max_flagged_fraction"):
        TrackingParams(contour_max_flagged_fraction=0.0)


def _track(params: TrackingParams, n: int = 8):
    (tex_b, tex_w), *_ = _scene()
    poses = [se3_exp(np.array([0.01 * i, 0.005 * i, 0.03 * i, 0.0, 0.01 * i, 0.0])) for i in range(n)]
    tracker, mapper = Tracker(CALIB, params), LocalMapper(CALIB)
    keyframes, out = [], []
    for i, T in enumerate(poses):
        left, _ = render_board_scene(tex_b, tex_w, T, CALIB)
        right, _ = render_board_scene(tex_b, tex_w, T, CALIB, right=True)
        res = tracker.track(StereoFrame(i, 0.05 * i, left, right))
        assert res.status in ("init", "ok"), (i, res.lost_reason)
        if res.is_keyframe:
            keyframes.append(res.keyframe)
            tracker.apply_map_update(mapper.insert_keyframe(res.keyframe))
        err = se3_inv(T) @ res.T_world_cam
        out.append((res.T_world_cam, np.linalg.norm(err[:3, 3]), np.degrees(rotation_angle(err[:3, :3]))))
    return keyframes, out, mapper


def test_contour_points_are_monocular_and_make_no_landmarks_when_on():
    keyframes, out, _ = _track(TrackingParams(contour_enabled=True, **NO_SAD))
    first = keyframes[0]
    *_, depth = _scene()
    truth = _true_contour(depth, first.uv.astype(np.float64)) & (first.depth > 0)
    assert truth.sum() >= 5
    on_rim = truth & (first.u_right < 0)                   # stereo-matched rim points lost their right column
    assert on_rim.sum() >= 0.8 * truth.sum()
    assert np.all(first.new_landmark_ids[on_rim] < 0)      # ... and create no landmark
    assert (first.new_landmark_ids >= 0).sum() > 100        # the surfaces still do
    assert max(e for _, e, _ in out) < 0.01 and max(a for _, _, a in out) < 0.1


def test_flag_off_leaves_tracking_unchanged():
    # off, the contour settings are not consulted: the same poses and keyframes bit for bit whatever
    # they say, and rim points keep their stereo column and make landmarks
    kf_a, out_a, _ = _track(TrackingParams(**NO_SAD))
    kf_b, out_b, _ = _track(TrackingParams(contour_enabled=False, contour_window_px=9.0, contour_ratio=0.01,
                                           contour_downscale=1, **NO_SAD))
    assert [k.index for k in kf_a] == [k.index for k in kf_b]
    for (Ta, _, _), (Tb, _, _) in zip(out_a, out_b):
        np.testing.assert_array_equal(Ta, Tb)
    first = kf_a[0]
    *_, depth = _scene()
    truth = _true_contour(depth, first.uv.astype(np.float64)) & (first.depth > 0)
    assert np.all(first.u_right[truth] >= 0) and np.all(first.new_landmark_ids[truth] >= 0)
    kf_on, _, _ = _track(TrackingParams(contour_enabled=True, **NO_SAD))
    assert (kf_on[0].u_right < 0).sum() > (first.u_right < 0).sum()  # and on, it does change them


def test_contour_landmarks_keeps_rim_points_in_the_map_as_bearing_only():
    # tracking.contour_landmarks: rim points still lose their right column (bearing-only in
    # tracking and BA) but now make landmarks at their stereo depth. In this clean scene with the
    # SAD test off the sliding rim landmarks cost frame 4 its inliers (docs/notes/s7-drift.md), so
    # four frames only
    keyframes, out, _ = _track(TrackingParams(contour_enabled=True, contour_landmarks=True, **NO_SAD), n=4)
    first = keyframes[0]
    *_, depth = _scene()
    truth = _true_contour(depth, first.uv.astype(np.float64)) & (first.depth > 0)
    on_rim = truth & (first.u_right < 0)
    assert on_rim.sum() >= 0.8 * truth.sum()
    assert np.all(first.new_landmark_ids[on_rim] >= 0)
    assert max(e for _, e, _ in out) < 0.01 and max(a for _, _, a in out) < 0.1


def test_turn_gate_tests_only_frames_whose_motion_turns_enough():
    # tracking.contour_min_rotation_deg: the scene's camera turns 0.57 deg a frame. Above that the
    # gate never opens and tracking is the contour-off run bit for bit; below it the first frame (no
    # motion model yet) is untested and the later keyframes' rim points are bearing-only
    kf_off, out_off, _ = _track(TrackingParams(**NO_SAD))
    kf_hi, out_hi, _ = _track(TrackingParams(contour_enabled=True, contour_min_rotation_deg=5.0, **NO_SAD))
    assert [k.index for k in kf_hi] == [k.index for k in kf_off]
    for (Ta, _, _), (Tb, _, _) in zip(out_off, out_hi):
        np.testing.assert_array_equal(Ta, Tb)
    kf_lo, out_lo, _ = _track(TrackingParams(contour_enabled=True, contour_min_rotation_deg=0.3, **NO_SAD))
    np.testing.assert_array_equal(kf_lo[0].u_right, kf_off[0].u_right)
    later = [k for k in kf_lo if k.index >= 2]
    assert later
    poses = [se3_exp(np.array([0.01 * i, 0.005 * i, 0.03 * i, 0.0, 0.01 * i, 0.0])) for i in range(8)]
    for k in later:
        *_, depth = _scene(poses[k.index])  # the exact depth seen from that keyframe (_track's poses)
        truth = _true_contour(depth, k.uv.astype(np.float64)) & (k.depth > 0)
        assert truth.sum() >= 5 and (truth & (k.u_right < 0)).sum() >= 0.6 * truth.sum()  # frame 0: none
    assert max(e for _, e, _ in out_lo) < 0.01 and max(a for _, _, a in out_lo) < 0.1


def test_turn_gate_setting_is_checked():
    with pytest.raises(ConfigError, match="contour_min_rotation_deg"):
        TrackingParams(contour_min_rotation_deg=-1.0)
