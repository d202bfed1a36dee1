"""Types shared by sources, algorithms and actors.

Conventions (used everywhere in the project):
- Poses are 4x4 float64 homogeneous matrices ``T_a_b`` mapping points in frame
  ``b`` to frame ``a``. A camera trajectory stores ``T_world_cam`` for the
  rectified left camera (x right, y down, z forward).
- Timestamps are float seconds.
- Images are uint8, single channel (grey) unless stated otherwise.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class StereoCalibration:
    """Pinhole model of a rectified stereo pair (both cameras share K).

    The right camera sits at +baseline along the left camera's x axis, so a
    point (X, Y, Z) in the left frame has disparity ``fx * baseline / Z``.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    baseline: float  # metres
    width: int
    height: int

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def bf(self) -> float:
        """Baseline times focal length: depth = bf / disparity."""
        return self.baseline * self.fx

    def to_dict(self) -> dict:
        return {k: getattr(self, k) for k in ("fx", "fy", "cx", "cy", "baseline", "width", "height")}


@dataclass
class StereoFrame:
    """One rectified stereo pair."""

    index: int
    timestamp: float
    left: np.ndarray
    right: np.ndarray


@dataclass
class Trajectory:
    """Timestamped poses T_world_cam, shape (N,) and (N, 4, 4)."""

    stamps: np.ndarray
    poses: np.ndarray
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        self.stamps = np.asarray(self.stamps, dtype=np.float64).reshape(-1)
        self.poses = np.asarray(self.poses, dtype=np.float64).reshape(-1, 4, 4)
        if len(self.stamps) != len(self.poses):
            raise ValueError(f"trajectory has {len(self.stamps)} stamps but {len(self.poses)} poses")

    def __len__(self) -> int:
        return len(self.stamps)

    @property
    def positions(self) -> np.ndarray:
        return self.poses[:, :3, 3]

    def path_length(self) -> float:
        p = self.positions
        return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum()) if len(p) > 1 else 0.0
