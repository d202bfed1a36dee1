"""The keyframes' measured up for local mapping's attitude prior (tracking.vertical_estimate; issue 9), and
the same measurement as a prior in every frame's motion-only refinement (tracking.vertical_track_prior).

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

from canopy.frontend.geometry import se3_inv


class KeyframeVertical:
    """Measures the up of keyframes and keeps the map segment's reference for the search gate."""

    def __init__(self, calib, max_sigma_deg: float, sigma_scale: float = 1.0):
        self.K = calib.K
        self.max_sigma_deg = float(max_sigma_deg)
        self.sigma_scale = float(sigma_scale)   # applied after the max_sigma_deg test
        self.up_world: np.ndarray | None = None
        self._last: tuple[int, np.ndarray, float] | None = None   # (frame index, up, sigma) of the last measurement
        # tracking.vertical_gate_keyframes: the segment's last keyframes' gate verdicts (canopy.frontend.vertical_gate)
        self.gate_history: list[bool] = []

    def restart(self) -> None:
        """A new map segment: its world is another one (no gate until its first measurement)."""
        self.up_world = None
        self.gate_history.clear()   # the new segment's keyframes start their own streak

    def measure(self, image: np.ndarray, T_world_cam: np.ndarray, index: int = -1) -> tuple[np.ndarray, float]:
        """(up_cam (3,), sigma deg) of the frame, (NaN x 3, NaN) when the image tells too little. A keyframe
        made from a frame already measured (``index``: its frame index) reuses that measurement."""
        from canopy.lines.vertical import estimate_vertical

        if self._last is not None and index >= 0 and self._last[0] == index and self.up_world is not None:
            return self._last[1].copy(), self._last[2]
        R_wc = T_world_cam[:3, :3]
        prior = None if self.up_world is None else R_wc.T @ self.up_world
        est = estimate_vertical(image, self.K, prior_up_cam=prior)
        if est is None or not est.sigma_deg <= self.max_sigma_deg:
            up, sigma = np.full(3, np.nan), float("nan")
        else:
            up = np.asarray(est.up_cam, float) / np.linalg.norm(est.up_cam)
            sigma = float(est.sigma_deg) * self.sigma_scale
            if self.up_world is None:
                self.up_world = R_wc @ up
        self._last = (index, up, sigma)
        return up.copy(), sigma

    def frame_term(self, image: np.ndarray, T_pred_cw: np.ndarray, index: int):
        """The motion-only refinement's attitude term of a frame (``AttitudePoseTerm``), gated by the predicted
        pose; None before the segment's first measurement or when the image tells too little."""
        from canopy.backend.attitude_prior import AttitudePoseTerm

        if self.up_world is None:
            return None
        up, sigma = self.measure(image, se3_inv(T_pred_cw), index)
        if not np.isfinite(sigma):
            return None
        return AttitudePoseTerm(up, self.up_world, np.radians(sigma))


class SummedTerms:
    """Two ``refine_pose`` extra terms as one (the motion prior and the attitude term)."""

    def __init__(self, *terms):
        self.terms = [t for t in terms if t is not None]

    def start_round(self) -> int:
        return sum(t.start_round() for t in self.terms)

    def normal_equations(self, T_cw: np.ndarray, robust: bool):
        H, g = np.zeros((6, 6)), np.zeros(6)
        for t in self.terms:
            He, ge = t.normal_equations(T_cw, robust)
            H += He
            g += ge
        return H, g

    def classify(self, T_cw: np.ndarray) -> None:
        for t in self.terms:
            t.classify(T_cw)

    def information(self, T_cw: np.ndarray) -> np.ndarray:
        return sum((t.information(T_cw) for t in self.terms), np.zeros((6, 6)))


def with_attitude(prior, attitude):
    """``prior`` and ``attitude`` as one extra term of ``refine_pose`` (either may be None)."""
    if attitude is None:
        return prior
    return attitude if prior is None else SummedTerms(prior, attitude)


def keyframe_vertical(tracker) -> KeyframeVertical:
    """The tracker's measurer (made on first use: both switches share it, and with it the segment's reference)."""
    vert = tracker.__dict__.get("_vertical")
    if vert is None:
        vert = tracker.__dict__["_vertical"] = KeyframeVertical(tracker.calib, tracker.params.vertical_max_sigma_deg,
                                                                tracker.params.vertical_sigma_scale)
    return vert


def frame_attitude_term(tracker, frame, T_pred_cw: np.ndarray):
    """tracking.vertical_track_prior: the attitude term of the frame being tracked (None: none)."""
    return keyframe_vertical(tracker).frame_term(frame.left, T_pred_cw, frame.index)
