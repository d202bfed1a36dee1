"""Rotations and rigid transforms shared by sources, metrics and I/O (pure numpy).

Quaternions are Hamilton, w first, as in EuRoC's ground truth; TUM files
store them x, y, z, w and the readers reorder.
"""
from __future__ import annotations

import numpy as np


def quat_wxyz_to_rot(q) -> np.ndarray:
    """Rotation matrices from Hamilton quaternions (w, x, y, z).

    ``q`` is (4,) or (N, 4); the result is (3, 3) or (N, 3, 3). Quaternions
    are normalised first; a zero or non-finite quaternion raises ValueError.
    """
    q = np.asarray(q, dtype=np.float64)
    single = q.ndim == 1
    q = q.reshape(-1, 4)
    norm = np.linalg.norm(q, axis=1)
    if not np.all(np.isfinite(norm)) or np.any(norm == 0.0):
        raise ValueError("quaternion with zero or non-finite norm")
    w, x, y, z = (q / norm[:, None]).T
    R = np.empty((len(q), 3, 3))
    R[:, 0, 0] = 1 - 2 * (y * y + z * z)
    R[:, 0, 1] = 2 * (x * y - w * z)
    R[:, 0, 2] = 2 * (x * z + w * y)
    R[:, 1, 0] = 2 * (x * y + w * z)
    R[:, 1, 1] = 1 - 2 * (x * x + z * z)
    R[:, 1, 2] = 2 * (y * z - w * x)
    R[:, 2, 0] = 2 * (x * z - w * y)
    R[:, 2, 1] = 2 * (y * z + w * x)
    R[:, 2, 2] = 1 - 2 * (x * x + y * y)
    return R[0] if single else R


def rot_to_quat_wxyz(R) -> np.ndarray:
    """Hamilton quaternions (w, x, y, z) with w >= 0 from (3, 3) or (N, 3, 3).

    Shepperd's method: pick the largest of w, x, y, z for a stable division.
    """
    R = np.asarray(R, dtype=np.float64)
    single = R.ndim == 2
    R = R.reshape(-1, 3, 3)
    tr = np.trace(R, axis1=1, axis2=2)
    diag = np.stack([tr, R[:, 0, 0], R[:, 1, 1], R[:, 2, 2]], axis=1)
    k = np.argmax(diag, axis=1)
    q = np.empty((len(R), 4))
    r = R
    # case w largest
    m = k == 0
    s = np.sqrt(1.0 + tr[m]) * 2.0
    q[m] = np.stack([0.25 * s, (r[m, 2, 1] - r[m, 1, 2]) / s, (r[m, 0, 2] - r[m, 2, 0]) / s,
                     (r[m, 1, 0] - r[m, 0, 1]) / s], axis=1)
    m = k == 1
    s = np.sqrt(1.0 + r[m, 0, 0] - r[m, 1, 1] - r[m, 2, 2]) * 2.0
    q[m] = np.stack([(r[m, 2, 1] - r[m, 1, 2]) / s, 0.25 * s, (r[m, 0, 1] + r[m, 1, 0]) / s,
                     (r[m, 0, 2] + r[m, 2, 0]) / s], axis=1)
    m = k == 2
    s = np.sqrt(1.0 - r[m, 0, 0] + r[m, 1, 1] - r[m, 2, 2]) * 2.0
    q[m] = np.stack([(r[m, 0, 2] - r[m, 2, 0]) / s, (r[m, 0, 1] + r[m, 1, 0]) / s, 0.25 * s,
                     (r[m, 1, 2] + r[m, 2, 1]) / s], axis=1)
    m = k == 3
    s = np.sqrt(1.0 - r[m, 0, 0] - r[m, 1, 1] + r[m, 2, 2]) * 2.0
    q[m] = np.stack([(r[m, 1, 0] - r[m, 0, 1]) / s, (r[m, 0, 2] + r[m, 2, 0]) / s,
                     (r[m, 1, 2] + r[m, 2, 1]) / s, 0.25 * s], axis=1)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 0] < 0] *= -1.0
    return q[0] if single else q


def poses_from_xyz_quat_wxyz(xyz, q_wxyz) -> np.ndarray:
    """(N, 4, 4) poses from positions (N, 3) and quaternions (N, 4)."""
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    P = np.tile(np.eye(4), (len(xyz), 1, 1))
    P[:, :3, :3] = quat_wxyz_to_rot(np.asarray(q_wxyz, dtype=np.float64).reshape(-1, 4))
    P[:, :3, 3] = xyz
    return P


# --------------------------------------------------------------------------- parsing
