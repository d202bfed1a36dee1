"""Left-right consistency of refined stereo matches (occlusion boundaries, silhouettes).

A corner on a silhouette (a tree crown against the sky, a trunk against far ground) is no
fixed 3D point, and the SAD window of its stereo match mixes foreground and background, which
the two cameras see differently. Matching back from the right image to the left finds a
different column there: a match is kept only when the right patch, searched along the left
row, lands on the left keypoint again (Fua 1993's left-right check, as in semi-global stereo).
"""
from __future__ import annotations

import numpy as np

from canopy.frontend.features import Features
from canopy.frontend.params import TrackingParams
from canopy.frontend.stereo import StereoMatches, subpixel_refine


def left_right_consistent(left: Features, stereo: StereoMatches, left_img: np.ndarray, right_img: np.ndarray,
                          params: TrackingParams) -> np.ndarray:
    """(N,) mask: valid stereo matches whose right patch refines back onto the left keypoint
    within ``params.stereo_lr_tolerance`` px of the keypoint's level."""
    ok = np.zeros(len(left), bool)
    idx = np.flatnonzero(stereo.valid)
    if len(idx) == 0:
        return ok
    s = params.scale_factor ** np.arange(params.n_levels)
    lvl = left.octave[idx]
    ur = stereo.u_right[idx].astype(np.float64) + params.disparity_offset_px  # back to the image's column
    uv_r = np.column_stack([ur, left.uv[idx, 1].astype(np.float64)])
    ul_back, _, good = subpixel_refine(right_img, left_img, uv_r, left.uv[idx, 0].astype(np.float64), lvl, s,
                                       params.subpixel_window, params.subpixel_search)
    # the right patch is centred on its rounded level column: its left match moves with it
    centre_shift = np.round(ur / s[lvl]) * s[lvl] - ur
    err = np.abs(ul_back - (left.uv[idx, 0] + centre_shift)) / s[lvl]
    ok[idx] = good & (err <= params.stereo_lr_tolerance)
    return ok


def drop_inconsistent(stereo: StereoMatches, keep: np.ndarray) -> StereoMatches:
    bad = stereo.valid & ~keep
    return StereoMatches(np.where(bad, -1.0, stereo.u_right).astype(np.float32),
                         np.where(bad, -1.0, stereo.depth).astype(np.float32), stereo.n_candidates)
