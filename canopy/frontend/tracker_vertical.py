"""The keyframes' measured up for local mapping's attitude prior (tracking.vertical_estimate; issue 9).

On a keyframe only (one segment detection per keyframe: its cost is measured in docs/notes/s25-attitude.md)
the left image the tracker sees (enhanced when the enhancement ran) goes to ``canopy.lines.vertical``'s
``estimate_vertical``; the result rides on the ``KeyframeData`` (``up_cam``, ``up_sigma_deg``) and local
BA pins the keyframe's pitch and roll with it (``canopy.backend.attitude_prior``, mapping.attitude_prior).

The estimator's search is gated by the up the tracker predicts: the segment's first measurement taken to
the world by its keyframe's pose (the same reference local mapping builds with
mapping.attitude_reference_keyframes = 1), brought into the new keyframe's camera by its tracked pose.
"""
from __future__ import annotations

import numpy as np


class KeyframeVertical:
    """Measures the up of keyframes and keeps the map segment's reference for the search gate."""

    def __init__(self, calib, max_sigma_deg: float):
        self.K = calib.K
        self.max_sigma_deg = float(max_sigma_deg)
        self.up_world: np.ndarray | None = None

    def restart(self) -> None:
        """A new map segment: its world is another one (no gate until its first measurement)."""
        self.up_world = None

    def measure(self, image: np.ndarray, T_world_cam: np.ndarray) -> tuple[np.ndarray, float]:
        """(up_cam (3,), sigma deg) of the keyframe, (NaN x 3, NaN) when the image tells too little."""
        from canopy.lines.vertical import estimate_vertical

        R_wc = T_world_cam[:3, :3]
        prior = None if self.up_world is None else R_wc.T @ self.up_world
        est = estimate_vertical(image, self.K, prior_up_cam=prior)
        if est is None or not est.sigma_deg <= self.max_sigma_deg:
            return np.full(3, np.nan), float("nan")
        up = np.asarray(est.up_cam, float) / np.linalg.norm(est.up_cam)
        if self.up_world is None:
            self.up_world = R_wc @ up
        return up, float(est.sigma_deg)
