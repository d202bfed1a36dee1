"""When a tracked frame becomes a keyframe (AGRI §3.2.4, Eq. 6-7 after Kerl et al. 2013, with
ORB-SLAM2's stereo conditions as safety rules). Pure functions of the tracker's counts."""
from __future__ import annotations

import numpy as np

from canopy.frontend.params import TrackingParams


def entropy_ratio(entropy: float | None, entropy_first: float | None) -> float | None:
    """AGRI Eq. 7: alpha = H(T_k:k+j) / H(T_k:k+1). Entropies are negative for a well constrained
    pose, so the ratio falls as the uncertainty grows with the distance to the keyframe; None when
    either entropy is missing or the first one is not negative."""
    if entropy is None or entropy_first is None or not np.isfinite(entropy) or entropy_first >= 0:
        return None
    return float(entropy / entropy_first)


def keyframe_reasons(p: TrackingParams, frames_since_kf: int, ratio: float | None, n_ref: int,
                     ref_tracked_first: int | None, n_tracked_close: int, n_new_close: int) -> list[str]:
    """The keyframe conditions that fire: "entropy" (Eq. 7 below alpha), "max_frames",
    "tracked_fraction" (fewer of the reference keyframe's landmarks than min_tracked_fraction of
    the first frame after it), "close_points" (ORB-SLAM2 stereo: few tracked close points and
    many new ones)."""
    reasons = []
    if ratio is not None and ratio < p.entropy_ratio_alpha:
        reasons.append("entropy")
    if frames_since_kf >= p.max_frames_between_keyframes:
        reasons.append("max_frames")
    if ref_tracked_first is not None and n_ref < p.min_tracked_fraction * ref_tracked_first:
        reasons.append("tracked_fraction")
    if n_tracked_close < p.min_tracked_close and n_new_close > p.min_new_close_points:
        reasons.append("close_points")
    return reasons
