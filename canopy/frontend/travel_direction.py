"""The direction of travel in the camera frame as a prior of motion-only refinement
(tracking.travel_direction_sigma_deg; issue 9).

A camera bolted to a car moves where the car points: the wheels do not slip sideways (the
non-holonomic constraint of a wheeled vehicle; Scaramuzza, "1-Point-RANSAC Structure from Motion for
Vehicle-Mounted Cameras by Exploiting Non-holonomic Constraints", IJCV 2011, §3). Between two frames
the camera centre moves along the chord of a circular arc, whose direction in the first camera's frame
is the rig's direction of travel turned by half the rotation between the frames (ibid., Eq. 3: the
chord's angle is theta / 2). So the step's direction *in the camera frame* is a property of the rig,
not of the scene: on KITTI 06's ground truth it stays within ~2 mrad of its running median, while on a
hazy noisy frame, which only near points hold, the estimate scatters ~15 mrad across the direction of
travel: the yaw / sideways coupling (docs/notes/s24-kittinoisy.md §2).

``TravelDirection`` learns the direction from the tracker's own recent steps (the median over a window,
each step turned back by half its rotation); ``TravelDirectionTerm`` pulls the new step's two
components across the expected chord toward zero with a standard deviation of ``sigma`` radians times
the predicted step length. Along the chord (the step's length, the scale) it says nothing, and the
rotation it leaves to the points. A rig that sways or crabs (a hand-held camera, a drone, the generated
orchard's wobbling cart) breaks the assumption: the switch is per dataset, off by default.
"""
from __future__ import annotations

from collections import deque

import cv2
import numpy as np

from canopy.frontend.geometry import se3_inv, so3_exp


def _rotation_vector(R: np.ndarray) -> np.ndarray:
    """Axis-angle of a rotation matrix (cv2.Rodrigues, as MotionPrior's residual)."""
    rvec, _ = cv2.Rodrigues(np.ascontiguousarray(R, dtype=float))
    return rvec.reshape(3)


class TravelDirection:
    """The rig's direction of travel in its camera frame, from the last ``window`` tracked steps of at
    least ``min_step_m`` (fewer than ``min_steps`` of them: unknown)."""

    def __init__(self, window: int, min_steps: int, min_step_m: float):
        self.min_steps = int(min_steps)
        self.min_step_m = float(min_step_m)
        self._forward: deque[np.ndarray] = deque(maxlen=int(window))

    def add(self, T_last_cur: np.ndarray) -> None:
        """One tracked step: ``T_last_cur`` is the current camera in the last camera's frame (the
        tracker's velocity). Its chord, turned back by half the step's rotation, is the direction of
        travel at the last frame (Scaramuzza 2011, Eq. 3)."""
        t = np.asarray(T_last_cur[:3, 3], float)
        n = float(np.linalg.norm(t))
        if not np.isfinite(n) or n < self.min_step_m:
            return  # standing still: the direction is the noise's
        forward = so3_exp(-0.5 * _rotation_vector(T_last_cur[:3, :3])) @ (t / n)
        # a rig that reverses travels along the same line: the residual is blind to the sign, the median
        # is not, so every step is stored on the side of the first one
        if self._forward and float(forward @ self._forward[0]) < 0:
            forward = -forward
        self._forward.append(forward)

    def forward(self) -> np.ndarray | None:
        """The median direction of travel (unit, camera frame), None while too few steps are known."""
        if len(self._forward) < self.min_steps:
            return None
        m = np.median(np.asarray(self._forward), axis=0)
        n = float(np.linalg.norm(m))
        return m / n if n > 0 else None

    def expected_chord(self, T_last_pred: np.ndarray) -> np.ndarray | None:
        """The chord the next step should follow, in the last camera's frame, for the predicted
        relative pose ``T_last_pred`` (its rotation turns the direction of travel by half)."""
        m = self.forward()
        if m is None:
            return None
        return so3_exp(0.5 * _rotation_vector(T_last_pred[:3, :3])) @ m


class TravelDirectionTerm:
    """``refine_pose`` extra term: the step from the last frame, seen in the last camera's frame, has no
    component across ``chord`` (2 residuals, standard deviation ``sigma_rad`` x ``step_m``).

    With the left increment T <- exp(dx) T of ``refine_pose`` (dx = (omega, v)) the camera centre
    c = -R^T t moves by -R^T v to first order and not with omega, so the residual
    r = B^T R_last (c - c_last) (B: two unit vectors across the chord) has the Jacobian
    [0 | -B^T R_last R^T]. Like ``MotionPrior`` it has no inlier set and adds no information to the
    pose's (the entropy of AGRI Eq. 6 stays the measurements')."""

    def __init__(self, T_last_cw: np.ndarray, chord: np.ndarray, sigma_rad: float, step_m: float):
        self.R_last = np.asarray(T_last_cw[:3, :3], float)
        self.c_last = -self.R_last.T @ np.asarray(T_last_cw[:3, 3], float)
        chord = np.asarray(chord, float) / np.linalg.norm(chord)
        # two unit vectors across the chord
        a = np.eye(3)[int(np.argmin(np.abs(chord)))]
        b1 = np.cross(chord, a)
        b1 /= np.linalg.norm(b1)
        self.B = np.stack([b1, np.cross(chord, b1)])   # (2, 3)
        self.weight = 1.0 / (float(sigma_rad) * float(step_m)) ** 2

    def residual(self, T_cw: np.ndarray) -> np.ndarray:
        c = -T_cw[:3, :3].T @ T_cw[:3, 3]
        return self.B @ (self.R_last @ (c - self.c_last))

    def start_round(self) -> int:
        return 0  # a prior, not measurements: it does not count toward the 6 residuals a pose needs

    def normal_equations(self, T_cw: np.ndarray, robust: bool) -> tuple[np.ndarray, np.ndarray]:
        J = np.zeros((2, 6))
        J[:, 3:] = -self.B @ self.R_last @ T_cw[:3, :3].T
        r = self.residual(T_cw)
        # refine_pose solves H dx = g with g = J^T W (target - f): the target is 0
        return self.weight * J.T @ J, -self.weight * J.T @ r

    def classify(self, T_cw: np.ndarray) -> None:
        pass

    def information(self, T_cw: np.ndarray) -> np.ndarray:
        return np.zeros((6, 6))


def texture_gate_open(robust_sigma: float | None, noise_sigma: float | None, max_texture: float) -> bool:
    """``tracking.travel_direction_max_texture``: True when the prior may join this frame. 0: every frame;
    > 0: raw frames whose texture excess (the mean |Laplacian| noise sigma minus the robust one, the
    fill-in's haze test in canopy.frontend.stereo_fill) is below it: haze flattens it (KITTI 0.2-1.9 grey
    levels at beta 0.03-0.06, clean 3.4-4.5). Frames the enhancement changed (no robust sigma) do not."""
    if max_texture <= 0:
        return True
    if robust_sigma is None or noise_sigma is None:
        return False
    return float(noise_sigma) - float(robust_sigma) < max_texture


def travel_direction_term(direction: TravelDirection, T_last_wc: np.ndarray, velocity: np.ndarray,
                          sigma_deg: float) -> TravelDirectionTerm | None:
    """The frame's term from the tracker's last pose and its constant-velocity model (None while the
    direction is unknown or the rig stands still)."""
    chord = direction.expected_chord(velocity)
    step = float(np.linalg.norm(velocity[:3, 3]))
    if chord is None or step < direction.min_step_m:
        return None
    return TravelDirectionTerm(se3_inv(T_last_wc), chord, np.radians(sigma_deg), step)
