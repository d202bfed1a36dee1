"""Stereo fill-in by optical flow for the keypoints the descriptor matcher left unmatched
(``tracking.stereo_fill_sigma``; issue 9's lit hazy cells).

On a hazy frame the far half of the image (transmission e^(-beta d): 0.17 at 30 m for beta 0.06 /m)
keeps its corners only a few noise sigmas above the FAST threshold, so the right image's FAST fires
on a different subset of them: on KITTI's g1-b0.06 cells 31 % of the left keypoints farther than
20 m have a right keypoint within 2 px of their true column (clean KITTI: 66 %), and 16 % end with a
stereo match (clean 32 %; docs/notes/s13-haze.md). Without a stereo match a keypoint creates no
landmark (there is no two-view triangulation here), so the local map loses its far points -- the
ones that pin rotation -- and the per-frame rotation error grows 2.6x.

The flow matcher (canopy.frontend.stereo_flow: pyramidal LK left -> right on the refinement pair,
Bouguet 2001, with the forward-backward check of Kalal et al. 2010) needs no right keypoint. Here it
runs only on the left keypoints the descriptor matcher did not match, and its columns go through the
same SAD refinement, disparity offset and SAD acceptance (``refine_and_accept``); the descriptor
matches are kept as they are. It fires on frames whose robust noise sigma (Immerkaer / MAD, the
refinement's estimator) is at least ``stereo_fill_sigma``.
"""
from __future__ import annotations

import numpy as np

from canopy.frontend.features import Features
from canopy.frontend.noisy_features import refinement_pair
from canopy.frontend.params import TrackingParams
from canopy.frontend.stereo import StereoMatches, refine_and_accept
from canopy.frontend.stereo_flow import flow_right_columns
from shared.types import StereoCalibration


def fill_active(left: Features, params: TrackingParams) -> bool:
    """True when this frame's unmatched keypoints get the flow fill-in."""
    if not params.stereo_fill:
        return False
    sig = left.robust_noise_sigma
    if sig is None:  # no estimate: only an unbounded rule fires
        return params.stereo_fill_min_sigma <= 0 and params.stereo_fill_max_sigma <= 0
    top = params.stereo_fill_max_sigma
    return sig >= params.stereo_fill_min_sigma and (top <= 0 or sig < top)


def fill_unmatched_by_flow(matches: StereoMatches, left: Features, left_img: np.ndarray, right_img: np.ndarray,
                           calib: StereoCalibration, params: TrackingParams,
                           noise_sigma: float | None = None) -> StereoMatches:
    """``matches`` with the keypoints it leaves unmatched matched by LK flow where the flow and the
    SAD tests accept them (see the module docstring); the matched ones unchanged."""
    if len(matches.depth) != len(left):
        raise ValueError(f"fill_unmatched_by_flow: matches has {len(matches.depth)} entries for {len(left)} keypoints")
    todo = np.flatnonzero(~matches.valid)
    if len(todo) == 0:
        return matches
    scale_factors = params.scale_factor ** np.arange(params.n_levels)
    max_disp = params.max_disparity_fraction * calib.width
    ref_left, ref_right, _ = refinement_pair(left_img, right_img, params, left.robust_noise_sigma)
    fl_left, fl_right = (left_img, right_img) if params.stereo_fill_raw_flow else (ref_left, ref_right)
    ur_flow, ok = flow_right_columns(fl_left, fl_right, left.uv[todo].astype(np.float64), params, max_disp)
    li = todo[ok]
    li, ur, disp = refine_and_accept(ref_left, ref_right, left, li, ur_flow[ok], scale_factors, max_disp,
                                     params, noise_sigma)
    u_right, depth = matches.u_right.copy(), matches.depth.copy()
    u_right[li] = ur
    depth[li] = calib.bf / disp
    return StereoMatches(u_right, depth, n_candidates=matches.n_candidates, on_contour=matches.on_contour)
