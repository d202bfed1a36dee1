"""A prior on the keyframes' attitude (pitch and roll, not yaw) from a measured vertical (issue 9).

Why: on the dim hazy day-loop the keyframes' rotation random-walks, mostly in pitch, because haze
leaves ~24 far keypoints a frame to pin it (docs/notes/s24-dimhaze.md). The scene's vertical (trunks,
poles: ``canopy.lines.vertical``) is seen in every frame without far points, and fixes the camera's
pitch and roll against gravity, not its yaw.

The term: keyframe k carries a measured up direction ``u_k`` in its camera frame (x right, y down,
z forward) with an angular sigma. SLAM does not know the world's up; its reference ``g`` (world frame)
is taken from the measurements themselves: the normalised sigma-weighted mean of R_world_cam,j u_j over
the first ``attitude_reference_keyframes`` keyframes of the map segment that carry one (with the
generator's exact up and one keyframe that is the true up in SLAM's world, the first keyframe's
pose being the world). Then for every local keyframe with a measurement the 2-D residual

    r_k = B_k^T (R_cam_world,k g),        B_k: an orthonormal basis of the plane normal to u_k,

is, to first order, the angle (rad) between the predicted and the measured up, and the prior adds
|r_k|^2 / sigma_k^2 to the BA cost (GTSAM's AttitudeFactor, "nRb * bMeasured == nRef", with the same
first-order residual; its Pose3 version is what the GTSAM path of ``local_ba`` adds).

Pose increments act on the left of T_cam_world (``stereo_ba`` convention): R <- exp(w) R gives
d(R g) = w x (R g) = -[R g]x w, so dr/dw = -B^T [R g]x and dr/dv = 0.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def tangent_basis(u: np.ndarray) -> np.ndarray:
    """(m,3,2) orthonormal bases of the planes normal to the unit vectors ``u`` (m,3)."""
    u = np.asarray(u, float).reshape(-1, 3)
    # a helper axis far from u: x unless u is within 45 deg of it, then z
    helper = np.where((np.abs(u[:, 0]) < 0.7)[:, None], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0])
    b1 = np.cross(u, helper)
    b1 /= np.linalg.norm(b1, axis=1, keepdims=True)
    b2 = np.cross(u, b1)
    return np.stack([b1, b2], axis=2)


def attitude_residuals(R_cw: np.ndarray, up_cam: np.ndarray, up_world: np.ndarray,
                       basis: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Residuals (m,2) rad and their Jacobians (m,2,3) with respect to a left rotation increment of
    ``R_cw`` (m,3,3), for measured camera-frame ups ``up_cam`` (m,3) and the world reference (3,)."""
    B = tangent_basis(up_cam) if basis is None else basis
    pred = np.einsum("mij,j->mi", np.asarray(R_cw, float), np.asarray(up_world, float))   # R g, (m,3)
    r = np.einsum("mik,mi->mk", B, pred)
    # d(Rg) = w x p, so dr_k = b_k . (w x p) = w . (p x b_k): row k of the Jacobian is p x b_k
    J = np.cross(pred[:, None, :], B.transpose(0, 2, 1))
    return r, J


@dataclass(frozen=True)
class AttitudePriors:
    """The attitude terms of one BA problem: ``pose[i]`` indexes the solver's pose array (local poses
    only), ``up_cam[i]`` its measured up, ``sigma[i]`` its angular sigma (rad); ``up_world`` the
    reference."""

    pose: np.ndarray       # (m,) int
    up_cam: np.ndarray     # (m,3)
    sigma: np.ndarray      # (m,) rad
    up_world: np.ndarray   # (3,)

    def __len__(self) -> int:
        return len(self.pose)

    def cost(self, T_cw: np.ndarray) -> float:
        """0.5 sum |r|^2 / sigma^2 (the solver's cost convention, no kernel)."""
        if not len(self):
            return 0.0
        r, _ = attitude_residuals(T_cw[self.pose, :3, :3], self.up_cam, self.up_world)
        return float(0.5 * np.sum((r**2).sum(axis=1) / self.sigma**2))

    def add_normal_blocks(self, T_cw: np.ndarray, Hcc: np.ndarray, bc: np.ndarray) -> None:
        """Adds J^T J / sigma^2 and J^T (-r) / sigma^2 to the poses' 6x6 blocks ``Hcc`` and vectors ``bc``
        (the solver's residual is measurement - prediction; here the measurement is 0)."""
        if not len(self):
            return
        r, J = attitude_residuals(T_cw[self.pose, :3, :3], self.up_cam, self.up_world)
        w = 1.0 / self.sigma**2
        H = np.einsum("mki,mkj->mij", J, J) * w[:, None, None]
        g = -np.einsum("mki,mk->mi", J, r) * w[:, None]
        np.add.at(Hcc, (self.pose, slice(0, 3), slice(0, 3)), H)
        np.add.at(bc, (self.pose, slice(0, 3)), g)


class AttitudeStore:
    """The measured ups of the map's keyframes and the reference of each map segment."""

    def __init__(self, reference_keyframes: int = 1):
        self.reference_keyframes = int(reference_keyframes)
        self.up_cam: dict[int, np.ndarray] = {}      # keyframe index -> (3,) unit
        self.sigma: dict[int, float] = {}            # keyframe index -> rad
        self._sum: dict[int, np.ndarray] = {}        # segment -> weighted sum of R_wc u
        self._count: dict[int, int] = {}
        self.segment_of: dict[int, int] = {}

    def add(self, index: int, segment: int, T_world_cam: np.ndarray, up_cam, sigma_deg: float) -> bool:
        """Records keyframe ``index``'s measurement (ignored when ``up_cam`` is not finite or sigma <= 0);
        the first ``reference_keyframes`` of the segment also build its reference from their poses as
        inserted. Returns whether it was recorded."""
        u = np.asarray(up_cam, float).reshape(3)
        if not (np.all(np.isfinite(u)) and np.isfinite(sigma_deg) and sigma_deg > 0 and np.linalg.norm(u) > 0):
            return False
        u = u / np.linalg.norm(u)
        s = float(np.radians(sigma_deg))
        self.up_cam[index], self.sigma[index], self.segment_of[index] = u, s, segment
        if self._count.get(segment, 0) < self.reference_keyframes:
            self._sum[segment] = self._sum.get(segment, np.zeros(3)) + (T_world_cam[:3, :3] @ u) / s**2
            self._count[segment] = self._count.get(segment, 0) + 1
        return True

    def reference(self, segment: int) -> np.ndarray | None:
        s = self._sum.get(segment)
        if s is None:
            return None
        return s / np.linalg.norm(s)

    def priors(self, local: list[int]) -> AttitudePriors | None:
        """The terms of the local keyframes ``local`` (pose i of the solver is ``local[i]``) that carry a
        measurement and whose segment has a reference; None when there are none."""
        rows = [(i, k) for i, k in enumerate(local) if k in self.up_cam]
        refs = [self.reference(self.segment_of[k]) for _, k in rows]
        rows = [(i, k, g) for (i, k), g in zip(rows, refs) if g is not None]
        if not rows:
            return None
        # one reference per problem: a window spans one segment (a restart's keyframes share no points)
        g = rows[-1][2]
        return AttitudePriors(pose=np.array([i for i, _, _ in rows], np.int64),
                              up_cam=np.stack([self.up_cam[k] for _, k, _ in rows]),
                              sigma=np.array([self.sigma[k] for _, k, _ in rows]), up_world=g)

    def discard(self, index: int) -> None:
        for d in (self.up_cam, self.sigma, self.segment_of):
            d.pop(index, None)


def attitude_factors(pose_keys: list[int], priors: AttitudePriors) -> list:
    """GTSAM factors of ``priors`` on the Pose3 (T_world_cam) variables ``pose_keys``: GTSAM's
    AttitudeFactor on Pose3, zero when R_world_cam u == g (its "nRb * bMeasured == nRef")."""
    import gtsam

    ref = gtsam.Unit3(np.asarray(priors.up_world, float))
    return [gtsam.AttitudeFactorPose3(key, ref, gtsam.noiseModel.Isotropic.Sigma(2, float(s)), gtsam.Unit3(u))
            for key, u, s in zip(pose_keys, priors.up_cam, priors.sigma)]


class AttitudePoseTerm:
    """The same prior on one pose in the tracker's motion-only refinement (``canopy.frontend.pose.refine_pose``'s
    ``extra`` terms): a pseudo-measurement, no kernel, no inlier set, no information added to the pose's."""

    def __init__(self, up_cam: np.ndarray, up_world: np.ndarray, sigma_rad: float):
        self.up_cam = np.asarray(up_cam, float).reshape(1, 3) / np.linalg.norm(up_cam)
        self.up_world = np.asarray(up_world, float).reshape(3)
        self.weight = 1.0 / float(sigma_rad) ** 2
        self.basis = tangent_basis(self.up_cam)

    def start_round(self) -> int:
        return 0   # a prior: it does not count toward the 6 residuals a pose needs

    def normal_equations(self, T_cw: np.ndarray, robust: bool) -> tuple[np.ndarray, np.ndarray]:
        r, J = attitude_residuals(T_cw[None, :3, :3], self.up_cam, self.up_world, self.basis)
        H, g = np.zeros((6, 6)), np.zeros(6)
        H[:3, :3] = self.weight * J[0].T @ J[0]
        g[:3] = -self.weight * J[0].T @ r[0]
        return H, g

    def classify(self, T_cw: np.ndarray) -> None:
        pass

    def information(self, T_cw: np.ndarray) -> np.ndarray:
        return np.zeros((6, 6))
