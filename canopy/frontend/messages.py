"""Tracking's per-frame result.

The data exchanged between tracking and local mapping (``KeyframeData``,
``LocalMapUpdate``) are wire messages and are defined once, in
``protocol.messages``; they are re-exported here for the algorithms.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


from protocol.messages import KeyframeData, LocalMapUpdate  # noqa: F401  (re-export)


@dataclass
class TrackingResult:
    index: int
    timestamp: float
    T_world_cam: np.ndarray
    status: str                  # "init" | "ok" | "predicted" (motion model, not tracked) | "lost"
    n_inliers: int
    n_matches: int
    is_keyframe: bool
    keyframe: KeyframeData | None
    reference_kf_index: int      # keyframe this frame's pose is expressed against (-1 if none)
    timings: dict[str, float] = field(default_factory=dict)
    pose_covariance: np.ndarray | None = None
    entropy: float | None = None        # AGRI Eq. 6 of this frame's pose estimate
    entropy_ratio: float | None = None  # AGRI Eq. 7, alpha for this frame
    n_stereo: int = 0
    # pose relative to the reference keyframe as tracking knew it (ORB-SLAM's relative frame
    # pose); with the keyframe's final pose it gives the frame's final pose. None when lost.
    T_ref_cam: np.ndarray | None = None
    keyframe_reason: str = ""    # which keyframe condition(s) fired: entropy, max_frames, ...
    n_lines: int = 0             # left segments detected (0 when tracking runs without lines)
    n_line_matches: int = 0      # segments matched to map lines
    n_line_inliers: int = 0      # line matches kept by the pose refinement
    line_rejected: dict = field(default_factory=dict)  # degenerate segments dropped at the boundary, by reason
    # why the frame has no tracked pose ("" when tracked): one of canopy.frontend.track_health.LOST_REASONS
    lost_reason: str = ""
    noise_sigma: float | None = None  # image noise estimate (grey levels) behind the FAST threshold floor
