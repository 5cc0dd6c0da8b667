"""Vectorized rotations for ensemble modules: planar angles, unit quaternions, matrices, orientation models.

Every function works on a stack of ``n`` rotations at once; :class:`Rotations2D` and :class:`Rotations3D`
hold the orientations of the refiners with their closed-form per-module fit. Quaternions are (w, x, y, z), the
convention of the ``decentral.ensemble/1`` estimate; a matrix ``R`` maps a vector written in the
module's local frame to the global frame (``v_global = R @ v_local``).
"""

from __future__ import annotations

import numpy as np

from decentral.ensemble.sparse_ops import row_matrix

__all__ = [
    "angle_to_matrix",
    "matrix_to_angle",
    "quat_to_matrix",
    "matrix_to_quat",
    "so3_exp",
    "project_to_rotation",
    "skew",
    "Rotations",
    "Rotations2D",
    "Rotations3D",
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

    The quaternion need not have unit norm: ``R(q) = R(q / |q|)`` (Funiak et al. 2008 §VI-D normalizes the
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
    """Nearest rotation matrices (n, d, d) (Frobenius norm) to the matrices ``M`` (n, d, d).

    2D has a closed form (the rotation by ``atan2(M10 - M01, M00 + M11)``). In 3D, matrices with a
    clearly positive determinant are projected by the scaled Newton iteration for the polar factor
    (``X <- (g X + X^-T / g) / 2``, ``g = |det X|^(-1/3)``), which converges quadratically and costs
    a few elementwise operations per matrix, about a quarter of a batched SVD; the others (rank
    deficient, reflected or slow to converge) go through the SVD with the determinant correction.
    """
    M = np.asarray(M, dtype=float)
    if M.shape[-1] == 2 and M.ndim == 3:
        a = M[:, 0, 0] + M[:, 1, 1]
        b = M[:, 1, 0] - M[:, 0, 1]
        h = np.hypot(a, b)
        ok = h > 0
        c = np.where(ok, a / np.where(ok, h, 1.0), 1.0)
        s = np.where(ok, b / np.where(ok, h, 1.0), 0.0)
        return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)
    if M.shape[-1] == 3 and M.ndim == 3 and M.shape[0] > 0:
        return _project_3d(M)
    return _project_svd(M)


def _project_svd(M: np.ndarray) -> np.ndarray:
    U, _, Vt = np.linalg.svd(np.asarray(M, dtype=float))
    det = np.linalg.det(U @ Vt)
    D = np.ones(U.shape[:-1])
    D[..., -1] = np.sign(det) + (det == 0)
    return (U * D[..., None, :]) @ Vt


def _cofactor(X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cofactor matrices (n, 3, 3) (= det X times X^-T) and determinants (n,) of ``X`` (n, 3, 3)."""
    a, b, c = X[:, 0, 0], X[:, 0, 1], X[:, 0, 2]
    d, e, f = X[:, 1, 0], X[:, 1, 1], X[:, 1, 2]
    g, h, i = X[:, 2, 0], X[:, 2, 1], X[:, 2, 2]
    C = np.empty_like(X)
    C[:, 0, 0] = e * i - f * h
    C[:, 0, 1] = f * g - d * i
    C[:, 0, 2] = d * h - e * g
    C[:, 1, 0] = c * h - b * i
    C[:, 1, 1] = a * i - c * g
    C[:, 1, 2] = b * g - a * h
    C[:, 2, 0] = b * f - c * e
    C[:, 2, 1] = c * d - a * f
    C[:, 2, 2] = a * e - b * d
    return C, a * C[:, 0, 0] + b * C[:, 0, 1] + c * C[:, 0, 2]


def _project_3d(M: np.ndarray, iterations: int = 12, tol: float = 1e-13) -> np.ndarray:
    out = np.empty_like(M)
    scale = np.sqrt(np.einsum("nab,nab->n", M, M))
    C, det = _cofactor(M)
    # well conditioned and not reflected: det(M) / |M|^3 bounded away from zero
    ok = det > 1e-3 * np.maximum(scale, 1e-300) ** 3
    idx = np.flatnonzero(ok)
    X = M[idx] / scale[idx, None, None]
    C, det = C[idx] / scale[idx, None, None] ** 2, det[idx] / scale[idx] ** 3
    done = np.zeros(idx.size, dtype=bool)
    for _ in range(iterations):
        g = np.abs(det) ** (-1.0 / 3.0)
        Xn = 0.5 * (g[:, None, None] * X + C / (g * det)[:, None, None])
        step = np.abs(Xn - X).reshape(-1, 9).max(axis=1)
        X = Xn
        done = step < tol
        if done.all():
            break
        C, det = _cofactor(X)
    out[idx[done]] = X[done]
    rest = np.concatenate([np.flatnonzero(~ok), idx[~done]])
    if rest.size:
        out[rest] = _project_svd(M[rest])
    return out


class Rotations:
    """Orientation model shared by 2D and 3D: observations as a sparse operator on stacked matrices.

    ``Z`` (E, d n) holds z_e at the columns (i_e, 0..d-1), so ``Z @ Rt`` with ``Rt[(i, b), a] =
    R_i[a, b]`` gives R_i z_e for every observation, and ``Z^T @ h`` gives the per-module sums
    M_i[a, b] = sum_e h_e[a] z_e[b] that the closed-form fit needs (Funiak et al. 2008 eq. (1) per module).
    """

    def __init__(self, i, z, n):
        d = z.shape[1]
        self.n, self.d = n, d
        self.Z = row_matrix(d * i[:, None] + np.arange(d), z, d * n)
        self.ZT = self.Z.T.tocsr()

    def rotate(self, R: np.ndarray) -> np.ndarray:
        """R_i z_e for every observation (E, d) from matrices R (n, d, d)."""
        return self.Z @ np.ascontiguousarray(R.transpose(0, 2, 1)).reshape(-1, self.d)

    def moments(self, dvec: np.ndarray) -> np.ndarray:
        """M (n, d, d), M_i[a, b] = sum_{e: i_e = i} dvec_e[a] z_e[b]."""
        return (self.ZT @ dvec).reshape(self.n, self.d, self.d).transpose(0, 2, 1)


class Rotations2D(Rotations):
    """Orientation state as angles (cheaper than matrices for the planar sweeps)."""

    def from_matrices(self, R):
        return matrix_to_angle(R)

    def to_matrices(self, theta):
        return angle_to_matrix(theta)

    def apply(self, theta):
        return self.rotate(angle_to_matrix(theta))

    def fit(self, dvec):
        # Funiak et al. 2008 eq. (1) per module, closed form: theta = atan2(sum z x d, sum z . d)
        M = self.moments(dvec)
        return np.arctan2(M[:, 1, 0] - M[:, 0, 1], M[:, 0, 0] + M[:, 1, 1])


class Rotations3D(Rotations):
    """Orientation state as matrices (n, 3, 3)."""

    def __init__(self, i, z, n):
        super().__init__(i, z, n)
        self.lonely = np.bincount(i, minlength=n) == 0

    def from_matrices(self, R):
        return np.asarray(R, float)

    def to_matrices(self, R):
        return R

    def apply(self, R):
        return self.rotate(R)

    def fit(self, dvec):
        # per-module Kabsch fit of R z_ij onto (c_j - c_i)/2
        M = self.moments(dvec)
        M[self.lonely] = np.eye(3)
        return project_to_rotation(M)
