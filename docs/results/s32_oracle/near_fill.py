"""s32: import to give every frame's stereo the flow fill-in (canopy.frontend.stereo_fill.fill_unmatched_by_flow:
LK left -> right for the keypoints the descriptor matcher left unmatched, then the same SAD refinement and tests),
keeping only the added matches whose disparity is at least NEAR_MIN_DISP px (environment, default 30): near points
(KITTI's road), which noise strips of their right keypoints (15 % noisy cell: 47 % of the clean run's near matches
have no right keypoint within 2 px) and which hold the scale. The descriptor matches and their SAD stay as they are."""
import os

import numpy as np

import canopy.frontend.tracker_worker as tw
from canopy.frontend.stereo import StereoMatches
from canopy.frontend.stereo_fill import fill_unmatched_by_flow

MIN_DISP = float(os.environ.get("NEAR_MIN_DISP", "30"))
STATS = {"frames": 0, "added": 0}
_orig = tw.match_stereo


def match_stereo(left, right, left_img, right_img, calib, params, noise_sigma=None, pyramids=None, sensor_sigma=None):
    st = _orig(left, right, left_img, right_img, calib, params, noise_sigma, pyramids, sensor_sigma)
    filled = fill_unmatched_by_flow(st, left, left_img, right_img, calib, params, noise_sigma, pyramids, "centre")
    new = (~st.valid) & filled.valid
    disp = np.where(filled.valid, calib.bf / np.where(filled.valid, filled.depth, 1.0), 0.0)
    add = new & (disp >= MIN_DISP)
    STATS["frames"] += 1
    STATS["added"] += int(add.sum())
    u_right = np.where(add, filled.u_right, st.u_right).astype(st.u_right.dtype)
    depth = np.where(add, filled.depth, st.depth).astype(st.depth.dtype)
    return StereoMatches(u_right, depth, n_candidates=st.n_candidates, on_contour=st.on_contour)


tw.match_stereo = match_stereo
