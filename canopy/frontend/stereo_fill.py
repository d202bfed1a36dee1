"""Stereo fill-in by optical flow for the keypoints the descriptor matcher left unmatched
(``tracking.stereo_fill``; issue 9's lit hazy cells).

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
matches are kept as they are (the SAD acceptance test's median is the added matches' own). It fires
on hazy frames whose pair the refinement does not smooth (``fill_active``): on KITTI's noisy sensor
(robust sigma >= 4, the pair Gaussian-smoothed) it added as many far stereo points but made the
trajectory worse on every noise draw (docs/notes/s13-haze.md).
"""
from __future__ import annotations

import numpy as np

from canopy.frontend.features import Features
from canopy.frontend.noisy_features import refinement_pair
from canopy.frontend.params import TrackingParams
from canopy.frontend.stereo import StereoMatches, refine_and_accept
from canopy.frontend.stereo_flow import flow_right_columns
from canopy.frontend.track_health import image_noise_sigma
from shared.types import StereoCalibration


def fill_active(left: Features, params: TrackingParams, left_img: np.ndarray | None = None,
                noise_sigma: float | None = None, sensor_sigma: float | None = None) -> bool:
    """True when this frame's unmatched keypoints get the flow fill-in: ``stereo_fill`` on, the
    robust noise sigma the extractor measured (``Features.robust_noise_sigma``) in
    [``stereo_fill_min_sigma``, ``stereo_fill_max_sigma``), and with ``stereo_fill_max_texture`` > 0
    the texture excess (``noise_sigma`` - robust sigma, the mean |Laplacian| estimate
    ``track_health.image_noise_sigma`` minus the median one; measured on ``left_img`` when
    ``noise_sigma`` is None) below it: haze flattens the texture (KITTI 0.2-1.9 grey levels at beta
    0.03-0.06, clean 3.4-4.5, the noise-only cells 2.4-4.1; canopy.frontend.noisy_features).
    Frames without a robust sigma (KITTI: those the enhancement changed) get no fill-in unless the
    band is unbounded, or ``sensor_fill_open`` says so (``stereo_fill_enhanced_min_sensor_sigma`` > 0:
    ``sensor_sigma`` is the enhancement's own noise figure of the frame)."""
    if not params.stereo_fill:
        return False
    sig = left.robust_noise_sigma
    if sig is None:
        if params.stereo_fill_enhanced_min_sensor_sigma > 0:
            return sensor_fill_open(sensor_sigma, params)
        return params.stereo_fill_min_sigma <= 0 and params.stereo_fill_max_sigma <= 0 and params.stereo_fill_max_texture <= 0
    if params.stereo_fill_max_texture > 0 and noise_sigma is None and left_img is None:
        raise ValueError("fill_active: stereo_fill_max_texture needs noise_sigma or left_img")
    return _in_band_and_flat(sig, params.stereo_fill_min_sigma, params.stereo_fill_max_sigma,
                             params.stereo_fill_max_texture, left_img, noise_sigma)


def _in_band_and_flat(robust: float, low: float, top: float, max_texture: float,
                      img: np.ndarray | None, noise_sigma: float | None) -> bool:
    """The raw-frame test: the robust sigma in [low, top) (top 0: unbounded) and, with max_texture > 0,
    the texture excess (the mean |Laplacian| sigma ``noise_sigma``, measured on ``img`` when None,
    minus the robust one) below max_texture."""
    if robust < low or (top > 0 and robust >= top):
        return False
    if max_texture <= 0:
        return True
    mean = image_noise_sigma(img) if noise_sigma is None else float(noise_sigma)
    return mean - robust < max_texture


def mean_on_noisy_haze(left: Features, params: TrackingParams, left_img: np.ndarray | None = None,
                       noise_sigma: float | None = None) -> bool:
    """True when this frame's stereo refinement gets the zero-mean SAD as a hazy frame of a noisy sensor
    (``subpixel_mean_on_noisy_haze``): the robust sigma the extractor measured at least
    ``subpixel_denoise_sigma`` (the pair the refinement runs on is smoothed, and the fill-in's gate,
    ``stereo_fill_max_sigma``, is shut) and the texture excess below ``stereo_fill_max_texture`` (haze;
    the noise-only frames keep 2.4-4.1 grey levels of it on KITTI, the hazy ones 0.2-1.9). Frames without
    a robust sigma (those the enhancement changed) do not.

    Why: the subtracted centre pixel carries the noise that the 2 px Gaussian leaves (about 0.14 x the
    noisy sensor's white 5-7 grey levels, more where it is not white) into every difference of a patch
    whose contrast the haze has cut to a few grey levels; the patch mean carries 1/11 of it. KITTI g1-b0.06-high seed 0, every 5th frame,
    the tracker's stereo matches against the clean pair's SGBM: > 1 px off 25 -> 20 % (< 15 m) and
    28 -> 21 % (15-30 m). Trajectory over fifteen noise draws: docs/notes/s24-kittinoisy.md, s24-lead.md."""
    if not params.subpixel_mean_on_noisy_haze or params.subpixel_denoise_sigma <= 0:
        return False
    sig = left.robust_noise_sigma
    if sig is None:
        return False
    if noise_sigma is None and left_img is None:
        raise ValueError("mean_on_noisy_haze: the texture test needs noise_sigma or left_img")
    return _in_band_and_flat(sig, params.subpixel_denoise_sigma, 0.0, params.stereo_fill_max_texture,
                             left_img, noise_sigma)


def sensor_fill_open(sensor_sigma: float | None, params: TrackingParams) -> bool:
    """The fill-in gate of a frame the enhancement changed, by the enhancement's own noise sigma of it
    (``info["noise_sigma"]``: ``estimate_noise`` on the AFE-lifted left image before the denoiser, the
    sigma the denoiser is set with; 0 on frames it did not denoise) in
    [``stereo_fill_enhanced_min_sensor_sigma``, ``stereo_fill_enhanced_max_sensor_sigma``) (max 0:
    unbounded). False without the figure (a caller that does not hand it over).

    Why this figure and not one measured on the enhanced image (s19's gate, removed): before the
    denoiser the lifted image still carries the sensor's noise times AFE's gain, which the scene's fine
    texture barely moves (the robust Immerkaer / MAD estimate), while after it the residual is
    mostly texture: the enhanced image's robust sigma kept the noisy day-loop cell (>= 2.17) apart from
    the clean presets (<= 1.83 where flat) by 0.3 grey levels (docs/notes/s19-dimfill.md); this figure
    reads 14.6-16.1 on that cell against at most 9.21 on every frame of the clean presets (dark frames
    are floored at ``auto_dark_min_sigma``, 4; docs/notes/s20-dimsigma.md)."""
    if sensor_sigma is None or sensor_sigma < params.stereo_fill_enhanced_min_sensor_sigma:
        return False
    top = params.stereo_fill_enhanced_max_sensor_sigma
    return top <= 0 or sensor_sigma < top


def fill_unmatched_by_flow(matches: StereoMatches, left: Features, left_img: np.ndarray, right_img: np.ndarray,
                           calib: StereoCalibration, params: TrackingParams,
                           noise_sigma: float | None = None, pyramids=None,
                           normalise: str | None = None) -> StereoMatches:
    """``matches`` with the keypoints it leaves unmatched matched by LK flow where the flow and the
    SAD tests accept them (see the module docstring); the matched ones unchanged. ``pyramids``: the
    raw pair's ``PairPyramids`` if built ahead (used when the refinement runs on the raw pair);
    ``normalise``: the SAD's patch normalisation if not ``params.subpixel_normalise``."""
    if len(matches.depth) != len(left):
        raise ValueError(f"fill_unmatched_by_flow: matches has {len(matches.depth)} entries for {len(left)} keypoints")
    todo = np.flatnonzero(~matches.valid)
    if len(todo) == 0:
        return matches
    scale_factors = params.scale_factor ** np.arange(params.n_levels)
    max_disp = params.max_disparity_fraction * calib.width
    ref_left, ref_right, _ = refinement_pair(left_img, right_img, params, left.robust_noise_sigma)
    ur_flow, ok = flow_right_columns(ref_left, ref_right, left.uv[todo].astype(np.float64), params, max_disp)
    li = todo[ok]
    li, ur, disp = refine_and_accept(ref_left, ref_right, left, li, ur_flow[ok], scale_factors, max_disp,
                                     params, noise_sigma, pyramids, normalise, raw_pair=(left_img, right_img))
    u_right, depth = matches.u_right.copy(), matches.depth.copy()
    u_right[li] = ur
    depth[li] = calib.bf / disp
    return StereoMatches(u_right, depth, n_candidates=matches.n_candidates, on_contour=matches.on_contour)


def appearance_first_matches(tracker, view, feats: Features, enough: int):
    """Stage 1 of a frame without a velocity (``tracking.appearance_first_filled``): the
    descriptor-only matches against the local map (ORB-SLAM's TrackReferenceKeyFrame) when this frame
    gets the fill-in and they are at least ``enough``, else None (the tracker's window search).

    Why: the fill-in adds far landmarks, and around a zero-motion prediction (the frame after an
    initialisation, 1.2 m off at KITTI's speed) far points project almost where they are seen: the
    40 px window matches then hold a RANSAC consensus of far points that fixes the rotation but not
    the translation (KITTI g1-b0.06-low with the fill-in: frame 1 214-314 mm off on three noise draws,
    12-16 mm with the descriptor matches first; docs/notes/s13-haze.md). ``tracker``: the Tracker
    (its ``params``, ``_frame_noise_sigma``, ``_frame_sensor_sigma`` and ``_appearance_matches``)."""
    sigma = getattr(tracker, "_frame_noise_sigma", None)
    p = tracker.params
    if p.stereo_fill_max_texture > 0 and sigma is None:
        return None  # the texture test needs the tracker's noise figure (fast_noise_factor > 0)
    if not fill_active(feats, p, None, sigma, getattr(tracker, "_frame_sensor_sigma", None)):
        return None
    cand = tracker._appearance_matches(view, feats)
    return cand if len(cand[1]) >= enough else None
