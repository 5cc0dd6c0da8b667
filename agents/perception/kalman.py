"""Constant-velocity Kalman filter over an image circle (u, v, r) and its rates, with circle IoU.

The state is ``x = [u, v, r, du, dv, dr]`` (pixels and pixels per frame). As in BoT-SORT [1]_, the
noise scales with the object's size: process and measurement standard deviations are fractions of
the radius, so near (large) and far (small) nodes are tracked alike.

References
----------
.. [1] N. Aharon, R. Orfaig, B.-Z. Bobrovsky, "BoT-SORT: Robust associations multi-pedestrian
   tracking", arXiv:2206.14651, 2022.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["KalmanConfig", "CircleKalman", "circle_iou", "warp_state"]


@dataclass(frozen=True)
class KalmanConfig:
    """Noise model, as fractions of the radius (``*_rel``) plus a floor in pixels (``*_abs``)."""

    pos_rel: float = 0.05
    vel_rel: float = 0.02
    meas_rel: float = 0.03
    meas_abs: float = 0.5
    init_vel_rel: float = 0.2


class CircleKalman:
    """Predict/update of one circle's state; pure numpy, no state beyond ``mean`` and ``cov``."""

    F = np.eye(6) + np.eye(6, k=3)
    Hm = np.eye(3, 6)

    def __init__(self, config: KalmanConfig | None = None):
        self.config = config or KalmanConfig()

    def initiate(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """State from a first measurement ``z`` = (u, v, r): mean (6,), covariance (6, 6)."""
        c = self.config
        r = max(float(z[2]), 1.0)
        mean = np.concatenate([np.asarray(z, dtype=float), np.zeros(3)])
        sd = np.array([2 * (c.meas_rel * r + c.meas_abs)] * 3 + [c.init_vel_rel * r] * 3)
        return mean, np.diag(sd**2)

    def predict(self, mean: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One frame ahead under constant velocity."""
        c = self.config
        r = max(float(mean[2]), 1.0)
        q = np.array([c.pos_rel * r] * 3 + [c.vel_rel * r] * 3) ** 2
        return self.F @ mean, self.F @ cov @ self.F.T + np.diag(q)

    def update(self, mean: np.ndarray, cov: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Correct with a measurement ``z`` = (u, v, r)."""
        c = self.config
        r = max(float(z[2]), 1.0)
        R = np.eye(3) * (c.meas_rel * r + c.meas_abs) ** 2
        S = self.Hm @ cov @ self.Hm.T + R
        K = np.linalg.solve(S, self.Hm @ cov).T
        mean = mean + K @ (np.asarray(z, dtype=float) - self.Hm @ mean)
        cov = (np.eye(6) - K @ self.Hm) @ cov
        return mean, 0.5 * (cov + cov.T)


def warp_state(mean: np.ndarray, cov: np.ndarray, H: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Move a circle state through the image homography ``H`` (3, 3) (camera-motion compensation).

    The centre maps through ``H``; the radius and the rates through its local Jacobian J at the
    centre (radius times sqrt|det J|, velocity J v).
    """
    u, v = mean[0], mean[1]
    p = H @ np.array([u, v, 1.0])
    if abs(p[2]) < 1e-12:
        return mean, cov
    x, y = p[0] / p[2], p[1] / p[2]
    J = (H[:2, :2] - np.outer([x, y], H[2, :2])) / p[2]
    s = float(np.sqrt(abs(np.linalg.det(J))))
    T = np.zeros((6, 6))
    T[:2, :2] = J
    T[2, 2] = s
    T[3:5, 3:5] = J
    T[5, 5] = s
    new = T @ mean
    new[0], new[1] = x, y
    return new, T @ cov @ T.T


def circle_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Intersection over union of discs, all pairs.

    Parameters
    ----------
    a : ndarray, shape (N, 3)
    b : ndarray, shape (M, 3)
        Circles (u, v, r).

    Returns
    -------
    ndarray, shape (N, M)
    """
    a = np.asarray(a, dtype=float).reshape(-1, 3)
    b = np.asarray(b, dtype=float).reshape(-1, 3)
    d = np.hypot(a[:, None, 0] - b[None, :, 0], a[:, None, 1] - b[None, :, 1])
    r1 = np.broadcast_to(a[:, None, 2], d.shape)
    r2 = np.broadcast_to(b[None, :, 2], d.shape)
    area1, area2 = np.pi * r1**2, np.pi * r2**2
    inter = np.zeros_like(d)
    inside = d <= np.abs(r1 - r2)
    inter[inside] = np.minimum(area1, area2)[inside]
    part = (d < r1 + r2) & ~inside
    if part.any():
        dd, a1, a2 = d[part], r1[part], r2[part]
        c1 = np.clip((dd**2 + a1**2 - a2**2) / (2 * dd * a1), -1.0, 1.0)
        c2 = np.clip((dd**2 + a2**2 - a1**2) / (2 * dd * a2), -1.0, 1.0)
        k = (-dd + a1 + a2) * (dd + a1 - a2) * (dd - a1 + a2) * (dd + a1 + a2)
        inter[part] = a1**2 * np.arccos(c1) + a2**2 * np.arccos(c2) - 0.5 * np.sqrt(np.maximum(k, 0.0))
    union = area1 + area2 - inter
    return np.where(union > 0, inter / np.maximum(union, 1e-12), 0.0)
