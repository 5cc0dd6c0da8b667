"""Vectorized rotations for ensemble modules: planar angles, unit quaternions and matrices.

Every function works on a stack of ``n`` rotations at once. Quaternions are (w, x, y, z), the
convention of the ``decentral.ensemble/1`` estimate; a matrix ``R`` maps a vector written in the
module's local frame to the global frame (``v_global = R @ v_local``).
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "angle_to_matrix",
    "matrix_to_angle",
    "quat_to_matrix",
    "matrix_to_quat",
    "so3_exp",
    "project_to_rotation",
    "skew",
]


def angle_to_matrix(theta: np.ndarray) -> np.ndarray:
    """Planar rotation matrices, shape (n, 2, 2), from angles ``theta`` (n,) in radians."""
    theta = np.asarray(theta, dtype=float)
    c, s = np.cos(theta), np.sin(theta)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def matrix_to_angle(R: np.ndarray) -> np.ndarray:
    """Angles (n,) in (-pi, pi] of planar rotation matrices ``R`` (n, 2, 2)."""
    R = np.asarray(R, dtype=float)
    return np.arctan2(R[..., 1, 0], R[..., 0, 0])


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (n, 3, 3) of quaternions ``q`` (n, 4) = (w, x, y, z), normalized implicitly.

    The quaternion need not have unit norm: ``R(q) = R(q / |q|)`` (seed 003 §VI-D normalizes the
    quaternion implicitly inside the observation model).
    """
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """Unit quaternions (n, 4) = (w, x, y, z) with w >= 0 of rotation matrices ``R`` (n, 3, 3).

    Uses the largest of the four diagonal combinations for each matrix (Shepperd's method), so it
    is accurate for every rotation.
    """
    R = np.asarray(R, dtype=float).reshape(-1, 3, 3)
    tr = R[:, 0, 0] + R[:, 1, 1] + R[:, 2, 2]
    cand = np.stack([tr, R[:, 0, 0], R[:, 1, 1], R[:, 2, 2]], -1)
    k = np.argmax(cand, axis=1)
    q = np.empty((R.shape[0], 4))
    # each branch computes the quaternion from the largest component for stability
    m = k == 0
    s = np.sqrt(np.maximum(1.0 + tr[m], 1e-300)) * 2
    q[m] = np.stack([0.25 * s, (R[m, 2, 1] - R[m, 1, 2]) / s, (R[m, 0, 2] - R[m, 2, 0]) / s,
                     (R[m, 1, 0] - R[m, 0, 1]) / s], -1)
    m = k == 1
    s = np.sqrt(np.maximum(1.0 + R[m, 0, 0] - R[m, 1, 1] - R[m, 2, 2], 1e-300)) * 2
    q[m] = np.stack([(R[m, 2, 1] - R[m, 1, 2]) / s, 0.25 * s, (R[m, 0, 1] + R[m, 1, 0]) / s,
                     (R[m, 0, 2] + R[m, 2, 0]) / s], -1)
    m = k == 2
    s = np.sqrt(np.maximum(1.0 + R[m, 1, 1] - R[m, 0, 0] - R[m, 2, 2], 1e-300)) * 2
    q[m] = np.stack([(R[m, 0, 2] - R[m, 2, 0]) / s, (R[m, 0, 1] + R[m, 1, 0]) / s, 0.25 * s,
                     (R[m, 1, 2] + R[m, 2, 1]) / s], -1)
    m = k == 3
    s = np.sqrt(np.maximum(1.0 + R[m, 2, 2] - R[m, 0, 0] - R[m, 1, 1], 1e-300)) * 2
    q[m] = np.stack([(R[m, 1, 0] - R[m, 0, 1]) / s, (R[m, 0, 2] + R[m, 2, 0]) / s,
                     (R[m, 1, 2] + R[m, 2, 1]) / s, 0.25 * s], -1)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 0] < 0] *= -1
    return q


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices (n, 3, 3) of vectors ``v`` (n, 3): ``skew(v) @ u == cross(v, u)``."""
    v = np.asarray(v, dtype=float)
    o = np.zeros(v.shape[:-1])
    return np.stack(
        [np.stack([o, -v[..., 2], v[..., 1]], -1),
         np.stack([v[..., 2], o, -v[..., 0]], -1),
         np.stack([-v[..., 1], v[..., 0], o], -1)],
        -2,
    )


def so3_exp(w: np.ndarray) -> np.ndarray:
    """Rotation matrices (n, 3, 3) ``exp(skew(w))`` of rotation vectors ``w`` (n, 3) (Rodrigues)."""
    w = np.asarray(w, dtype=float)
    theta = np.linalg.norm(w, axis=-1)
    small = theta < 1e-8
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    K = skew(w)
    return np.eye(3) + a[..., None, None] * K + b[..., None, None] * (K @ K)


def project_to_rotation(M: np.ndarray) -> np.ndarray:
    """Nearest rotation matrices (n, d, d) (Frobenius norm) to the matrices ``M`` (n, d, d)."""
    U, _, Vt = np.linalg.svd(np.asarray(M, dtype=float))
    det = np.linalg.det(U @ Vt)
    D = np.ones(U.shape[:-1])
    D[..., -1] = np.sign(det) + (det == 0)
    return (U * D[..., None, :]) @ Vt
