"""Level-0 coordinates of ORB keypoints found on pyramid levels, pixel centres aligned.

OpenCV's ORB builds level L by ``cv2.resize`` of level L-1 to (round(W / s^L), round(H / s^L))
(pixel *areas* aligned: x_{L-1} = (x_L + 0.5) w_{L-1} / w_L - 0.5) but reports a keypoint found
at level coordinate x_L as x_L * s^L: about 0.5 (s^L - 1) px up and left of where it was found
(0.1 px on level 1, 1.3 px on level 7 at scale 1.2), plus a small per-level zoom from the
rounded level sizes. Stereo disparities are unaffected (both images share the convention), but
a landmark created from a keypoint on one level and seen later on another is displaced by the
difference, the same way for every landmark: tracking absorbs it as a small rotation (pitch and
yaw) each time the map is renewed, which adds up where the map is renewed fast (turns).
``tests/test_keypoint_centres.py`` detects on an image and its mirror image: OpenCV's positions
disagree by the offsets above, the mapped ones agree on every level.
"""
from __future__ import annotations

import numpy as np

from canopy.frontend.features import Features
from canopy.frontend.stereo import StereoMatches


def level_maps(size: int, scale_factors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per level L: (a_L, b_L) with level-0 coordinate = a_L * reported + b_L along one image axis
    of ``size`` pixels, where reported = x_L * s^L is OpenCV's keypoint coordinate."""
    s = np.asarray(scale_factors, np.float64)
    n = np.array([float(int(np.floor(size / f + 0.5))) for f in s])  # cvRound(size / scale)
    A = np.ones(len(s))  # x_0 = A_L x_L + B_L, chained level by level (resize from level L-1)
    B = np.zeros(len(s))
    for L in range(1, len(s)):
        a = n[L - 1] / n[L]
        A[L] = A[L - 1] * a
        B[L] = A[L - 1] * (0.5 * a - 0.5) + B[L - 1]
    return A / s, B


def centre_keypoints(feats: Features, stereo: StereoMatches | None, scale_factors: np.ndarray,
                     width: int, height: int) -> tuple[Features, StereoMatches | None]:
    """``feats`` (and the right-image columns of ``stereo``) mapped to pixel-centre-aligned
    level-0 coordinates; depths are kept (disparities change by < 0.3 %)."""
    if len(feats) == 0:
        return feats, stereo
    ax, bx = level_maps(width, scale_factors)
    ay, by = level_maps(height, scale_factors)
    o = feats.octave
    uv = np.empty_like(feats.uv)
    uv[:, 0] = ax[o] * feats.uv[:, 0] + bx[o]
    uv[:, 1] = ay[o] * feats.uv[:, 1] + by[o]
    out = Features(uv, feats.octave, feats.response, feats.descriptors, feats.extractor)
    if stereo is None:
        return out, None
    ur = np.where(stereo.valid, ax[o] * stereo.u_right + bx[o], stereo.u_right).astype(np.float32)
    return out, StereoMatches(ur, stereo.depth, n_candidates=stereo.n_candidates)
