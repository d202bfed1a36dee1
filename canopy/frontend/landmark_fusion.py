"""Tracking-side refinement of landmark positions from every tracked frame's stereo measurements
(a structure-only bundle adjustment with the frames' poses held fixed, one Gauss-Newton step).

Why (docs/notes/s14-jitter.md): on a still camera the pose is per-frame jitter, and a still camera
makes keyframes only from the frame cap, so a landmark's position is a single keyframe's stereo
triangulation until the next keyframe's local BA (ORB-SLAM's LocalBundleAdjustment) averages it with
one more view. A keyframe every 3 frames made tracking steadier mostly through that averaging (local BA
switched off: 0.927 -> 0.819 mm on the hazy low-noise cell; on: 0.698), at ~14-22 ms of local mapping CPU
per frame. Every tracked frame already measures its stereo landmarks: fusing those measurements into
the positions tracking reads gives the averaging without a keyframe.

Model. A stereo measurement z = (u, v, u_r) of point P (camera frame) has Jacobian J = dz/dP
(Hartley & Zisserman's rectified stereo projection: u = fx x/z + cx, v = fy y/z + cy, u_r = u - bf/z)
and noise sigma(octave) on each coordinate, so the triangulated point X = T_wc pi^-1(z) carries the
information R J^T J R^T / sigma^2 (R = R_wc). With the poses fixed, the structure-only Gauss-Newton
solution for a landmark is the information-weighted mean of its measured points and of the map's
position (local mapping's BA result), which enters as a prior with ``prior_weight`` x the information of
the landmark's first fused measurement. Observations are kept across map updates (their frames' poses
do not move), and dropped on a new map segment or a loop correction (the map moved).
"""
from __future__ import annotations

import copy

import numpy as np

from shared.types import StereoCalibration


def stereo_point_information(Pc: np.ndarray, sigma: np.ndarray, R_wc: np.ndarray,
                             calib: StereoCalibration) -> np.ndarray:
    """(N,3,3) world-frame information of stereo-triangulated points ``Pc`` (camera frame, z > 0)
    measured with pixel noise ``sigma`` (N,) on u, v and u_r: R J^T J R^T / sigma^2."""
    Pc = np.asarray(Pc, float).reshape(-1, 3)
    if np.any(Pc[:, 2] <= 0):
        raise ValueError("stereo_point_information: Pc has a point at or behind the camera (z <= 0)")
    x, y, z = Pc[:, 0], Pc[:, 1], Pc[:, 2]
    iz = 1.0 / z
    J = np.zeros((len(Pc), 3, 3))
    J[:, 0, 0] = calib.fx * iz
    J[:, 0, 2] = -calib.fx * x * iz * iz
    J[:, 1, 1] = calib.fy * iz
    J[:, 1, 2] = -calib.fy * y * iz * iz
    J[:, 2, 0] = calib.fx * iz
    J[:, 2, 2] = -calib.fx * x * iz * iz + calib.bf * iz * iz
    Ic = np.einsum("nki,nkj->nij", J, J) / (np.asarray(sigma, float) ** 2)[:, None, None]
    return np.einsum("ij,njk,lk->nil", R_wc, Ic, R_wc)


class LandmarkFusion:
    """Information sums of the landmarks' per-frame stereo measurements, by landmark id."""

    def __init__(self, prior_weight: float = 1.0):
        if not prior_weight > 0:
            raise ValueError(f"LandmarkFusion: prior_weight must be > 0, got {prior_weight}")
        self.prior_weight = float(prior_weight)
        self.reset()

    def reset(self) -> None:
        self.info = np.zeros((0, 3, 3))     # sum of the measurements' information
        self.eta = np.zeros((0, 3))         # sum of information x measured point
        self.first = np.zeros((0, 3, 3))    # information of the first measurement (the prior's scale)
        self.count = np.zeros(0, np.int64)

    def _grow(self, n: int) -> None:
        if n <= len(self.count):
            return
        m = max(n, 2 * len(self.count), 1024)
        for name in ("info", "eta", "first", "count"):
            a = getattr(self, name)
            b = np.zeros((m,) + a.shape[1:], a.dtype)
            b[:len(a)] = a
            setattr(self, name, b)

    def add(self, ids: np.ndarray, Xw: np.ndarray, info: np.ndarray) -> None:
        """Fuse measured world points ``Xw`` (N,3) with information ``info`` (N,3,3) of landmarks ``ids``
        (distinct, >= 0)."""
        ids = np.asarray(ids, np.int64)
        if len(ids) == 0:
            return
        if ids.min() < 0:
            raise ValueError("LandmarkFusion.add: ids has a negative landmark id")
        self._grow(int(ids.max()) + 1)
        new = self.count[ids] == 0
        self.first[ids[new]] = info[new]
        np.add.at(self.info, ids, info)  # np.add.at: an id measured twice in a frame counts twice
        np.add.at(self.eta, ids, np.einsum("nij,nj->ni", info, Xw))
        np.add.at(self.count, ids, 1)

    def positions(self, ids: np.ndarray, map_pos: np.ndarray) -> np.ndarray:
        """The fused positions of landmarks ``ids`` whose map positions are ``map_pos``: the
        information-weighted mean of the map position (weight prior_weight x first measurement's)
        and the fused measurements; landmarks without measurements keep the map position."""
        ids = np.asarray(ids, np.int64)
        out = np.array(map_pos, float, copy=True).reshape(-1, 3)
        has = ids < len(self.count)
        sel = np.flatnonzero(has)
        sel = sel[self.count[ids[sel]] > 0]
        if len(sel) == 0:
            return out
        k = ids[sel]
        P = self.prior_weight * self.first[k]
        A = P + self.info[k]
        b = np.einsum("nij,nj->ni", P, out[sel]) + self.eta[k]
        out[sel] = np.linalg.solve(A, b[:, :, None])[:, :, 0]
        return out


def fused_view(view, fusion: LandmarkFusion):
    """A shallow copy of the map view ``view`` whose positions are ``fusion``'s (ids, descriptors shared)."""
    out = copy.copy(view)
    out.pos = fusion.positions(view.ids, view.pos)
    return out


def fuse_frame(tracker, T_wc: np.ndarray, ids: np.ndarray, r: np.ndarray, inliers: np.ndarray, feats, stereo) -> None:
    """Add one tracked frame's stereo measurements of its inlier landmarks (depth below the tracker's
    stereo-observation limit) to ``tracker._landmark_fusion``."""
    good = inliers & (ids >= 0)
    good[good] &= stereo.valid[r[good]]
    good[good] &= stereo.depth[r[good]] < min(tracker._stereo_obs_depth, tracker._max_depth)
    k = np.flatnonzero(good)
    if len(k) == 0:
        return
    rows = r[k]
    Xw = tracker._stereo_points_world(feats, stereo, T_wc, rows)
    Pc = (Xw - T_wc[:3, 3]) @ T_wc[:3, :3]
    info = stereo_point_information(Pc, tracker._sigma(feats.octave[rows]), T_wc[:3, :3], tracker.calib)
    tracker._landmark_fusion.add(ids[k], Xw, info)
