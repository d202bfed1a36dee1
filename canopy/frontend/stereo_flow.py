"""Stereo matching by optical flow (``tracking.stereo_matcher: flow``): no right-image ORB.

The right image's ORB keypoints and descriptors serve only to find each left keypoint's column in
the right image (canopy.frontend.stereo). Stereo visual odometry built on KLT tracking (VINS-Fusion's
feature tracker, OpenVINS) finds it instead by pyramidal Lucas-Kanade (Bouguet 2001, "Pyramidal
implementation of the affine Lucas Kanade feature tracker") from the left keypoints into the
rectified right image, and keeps a point only when

* the flow stays on the rectified row (|dy| <= ``flow_max_dy``),
* the disparity is in [``min_disparity``, ``max_disparity_fraction`` x width],
* the right->left flow of the found point comes back within ``flow_back_px`` of the keypoint
  (the forward-backward check of Kalal et al. 2010, which rejects flows that slid along an edge
  or jumped to a repeated structure).

The found column then goes through the descriptor matcher's own tail: the SAD sub-pixel refinement
(parabola on the keypoint's pyramid level, on the denoised pair for noisy frames), the rig's
disparity offset and the SAD outlier test (canopy.frontend.stereo.subpixel_refine,
canopy.frontend.noisy_features), so both matchers measure the final disparity the same way.
The cost is two cv2.calcOpticalFlowPyrLK calls (C++) instead of a second ORB extraction plus the
band search and Hamming distances (docs/notes/s11-speed.md).
"""
from __future__ import annotations

import cv2
import numpy as np

from canopy.frontend.features import Features
from canopy.frontend.noisy_features import refinement_pair
from canopy.frontend.params import TrackingParams
from canopy.frontend.stereo import StereoMatches, refine_and_accept
from shared.types import StereoCalibration



def flow_right_columns(left_img: np.ndarray, right_img: np.ndarray, uv: np.ndarray, params: TrackingParams,
                       max_disparity: float) -> tuple[np.ndarray, np.ndarray]:
    """Right-image column of each left point ``uv`` (N,2) by pyramidal LK and the mask of points
    that pass the row, disparity and back-track checks (see the module docstring)."""
    n = len(uv)
    if n == 0:
        return np.zeros(0, np.float64), np.zeros(0, bool)
    for name, img in (("left_img", left_img), ("right_img", right_img)):
        if img.ndim != 2 or img.dtype != np.uint8:
            raise ValueError(f"flow_right_columns: {name} must be a grey uint8 image "
                             f"(got shape {img.shape}, dtype {img.dtype})")
    win = (params.flow_window, params.flow_window)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, params.flow_iterations, 0.03)
    p0 = np.ascontiguousarray(uv, np.float32).reshape(-1, 1, 2)
    p1, st, _ = cv2.calcOpticalFlowPyrLK(left_img, right_img, p0, None, winSize=win,
                                         maxLevel=params.flow_levels, criteria=criteria, minEigThreshold=params.flow_min_eig)
    p1 = p1.reshape(-1, 2)
    ok = st.reshape(-1) == 1
    disp = uv[:, 0] - p1[:, 0]
    ok &= (np.abs(p1[:, 1] - uv[:, 1]) <= params.flow_max_dy)
    ok &= (disp >= params.min_disparity) & (disp <= max_disparity)
    idx = np.flatnonzero(ok)
    if len(idx) and params.flow_back_px > 0:
        # back-track only the survivors, starting from the keypoint itself (the flow's inverse)
        q1 = np.ascontiguousarray(p1[idx], np.float32).reshape(-1, 1, 2)
        q0 = p0[idx].copy()
        back, st_b, _ = cv2.calcOpticalFlowPyrLK(right_img, left_img, q1, q0, winSize=win,
                                                 maxLevel=params.flow_back_levels, criteria=criteria, minEigThreshold=params.flow_min_eig,
                                                 flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
        err = np.linalg.norm(back.reshape(-1, 2) - uv[idx], axis=1)
        ok[idx] = (st_b.reshape(-1) == 1) & (err <= params.flow_back_px)
    return p1[:, 0].astype(np.float64), ok


def match_stereo_flow(left: Features, left_img: np.ndarray, right_img: np.ndarray, calib: StereoCalibration,
                      params: TrackingParams, noise_sigma: float | None = None) -> StereoMatches:
    """Stereo matches of the left keypoints by LK flow, refined and tested as ``match_stereo``'s."""
    n = len(left)
    u_right = np.full(n, -1.0, np.float32)
    depth = np.full(n, -1.0, np.float32)
    if n == 0:
        return StereoMatches(u_right, depth)
    scale_factors = params.scale_factor ** np.arange(params.n_levels)
    max_disp = params.max_disparity_fraction * calib.width
    uv = left.uv.astype(np.float64)
    # the flow runs on the refinement's pair: on a noisy sensor (σ >= subpixel_denoise_sigma) both
    # images smoothed alike, which LK's gradients need more than the SAD does; clean frames: raw
    ref_left, ref_right, _ = refinement_pair(left_img, right_img, params, left.robust_noise_sigma)
    ur_flow, ok = flow_right_columns(ref_left, ref_right, uv, params, max_disp)
    li = np.flatnonzero(ok)
    n_flow = len(li)
    li, ur, disp = refine_and_accept(ref_left, ref_right, left, li, ur_flow[li], scale_factors, max_disp,
                                     params, noise_sigma, raw_pair=(left_img, right_img))
    u_right[li] = ur
    depth[li] = calib.bf / disp
    return StereoMatches(u_right, depth, n_candidates=n_flow)
