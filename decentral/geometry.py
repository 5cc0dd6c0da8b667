"""Planar-yaw geometry shared by the estimators.

Conventions (docs/formats.md): a pose "of B in A" maps ``x_A = R x_B + p``; horizontal frames have z up;
a yaw-only rotation is ``R = blkdiag(R2, 1)`` with ``R2`` in SO(2) (Liu et al. 2024 eq. (16)).
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "rot2",
    "rotz",
    "yaw_of",
    "wrap_angle",
    "project_so2",
    "backproject",
]


def rot2(theta: float | np.ndarray) -> np.ndarray:
    """SO(2) matrix (or stack (..., 2, 2)) of angle(s) ``theta`` in radians."""
    c, s = np.cos(theta), np.sin(theta)
    if np.ndim(theta) == 0:  # one angle: the filters' hot path, without the stacking
        return np.array([[c, -s], [s, c]])
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def rotz(theta: float | np.ndarray) -> np.ndarray:
    """Yaw rotation(s) about z, shape (3, 3) or (..., 3, 3) (Liu et al. 2024 eq. (16))."""
    theta = np.asarray(theta, dtype=float)
    R = np.zeros(theta.shape + (3, 3))
    R[..., :2, :2] = rot2(theta)
    R[..., 2, 2] = 1.0
    return R


def yaw_of(R: np.ndarray) -> float | np.ndarray:
    """Yaw angle (rad) of a rotation: the angle of its first column's xy part."""
    R = np.asarray(R)
    return np.arctan2(R[..., 1, 0], R[..., 0, 0])


def wrap_angle(theta: float | np.ndarray) -> float | np.ndarray:
    """Wrap angle(s) into [-pi, pi)."""
    return (np.asarray(theta) + np.pi) % (2 * np.pi) - np.pi


def project_so2(Y: np.ndarray) -> np.ndarray:
    """Nearest SO(2) matrix to each 2x2 block ``Y`` (..., 2, 2) in the Frobenius norm.

    .. math:: \\underline{R} = U \\operatorname{diag}(1, \\det(U V^T)) V^T, \\quad Y = U \\Sigma V^T

    Liu et al. 2024 eq. (17).
    """
    U, _, Vt = np.linalg.svd(Y)
    d = np.sign(np.linalg.det(U @ Vt))
    d[d == 0] = 1.0
    D = np.zeros(Y.shape)
    D[..., 0, 0] = 1.0
    D[..., 1, 1] = d
    return U @ D @ Vt


def backproject(K: np.ndarray, u: np.ndarray, v: np.ndarray, r: np.ndarray, node_radius: float) -> np.ndarray:
    """Node centres (n, 3) in the camera frame from image circles, by the radius as depth cue.

    .. math:: \\hat p^c_{N_i} = K^{-1} \\frac{f r_0}{r_i} [u_i, v_i, 1]^T

    Liu et al. 2024 eq. (1), with ``f`` the mean of the two focal lengths (they are equal for square pixels).

    Parameters
    ----------
    K : ndarray, shape (3, 3)
        Pinhole intrinsics.
    u, v, r : ndarray, shape (n,)
        Circle centres and radii in pixels (r > 0).
    node_radius : float
        The real node radius r_0 in metres.
    """
    u, v, r = (np.asarray(a, dtype=float) for a in (u, v, r))
    f = 0.5 * (K[0, 0] + K[1, 1])
    depth = f * node_radius / r
    rays = np.linalg.solve(K, np.stack([u, v, np.ones_like(u)]))  # (3, n), last row 1
    return (rays * depth).T
