"""From a sphere's image circle to the circle of seed 000 eq. (1) (centre projection, f r0 / z).

A sphere's silhouette in a pinhole image is an ellipse, not a circle: off the optical axis its best
circle is larger than ``f r0 / z`` and its centre is pushed outwards (5-8 % in radius at the edge of
a 1024 x 768 image with f = 760 px). The rim's rays form a cone around the ray to the sphere's centre
with half-angle ``asin(r0 / d)``: the unit rays of rim points lie on one plane ``a . x = cos(alpha)``.
Fitting that plane to points of the detected circle gives a first cone; since the detected circle
is itself a circle fitted to the elliptic silhouette, the cone is then corrected by a fixed-point
iteration: the circle fitted to the exact silhouette of the current cone is compared with the
detected one and the difference is fed back. The eq. (1) circle follows from the cone:
(u, v) = projection of ``a``, r = f sin(alpha) / a_z, which makes ``K^-1 (f r0 / r) [u, v, 1]`` the
sphere centre exactly.
"""

from __future__ import annotations

import numpy as np

from agents.perception.types import Circle

__all__ = ["eq1_circle", "silhouette_circle"]

_ANG = np.linspace(0.0, 2.0 * np.pi, 64, endpoint=False)


def _cone(u: float, v: float, r: float, Kinv: np.ndarray) -> tuple[np.ndarray, float]:
    pix = np.stack([u + r * np.cos(_ANG), v + r * np.sin(_ANG), np.ones(len(_ANG))], axis=1)
    rays = pix @ Kinv.T
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    mean = rays.mean(axis=0)
    _, _, vt = np.linalg.svd(rays - mean)
    a = vt[-1] if vt[-1][2] > 0 else -vt[-1]
    return a, float(np.clip(a @ mean, -1.0, 1.0))


def silhouette_circle(a: np.ndarray, cos_alpha: float, K: np.ndarray) -> np.ndarray:
    """Algebraic best circle (u, v, r) through the exact silhouette of the cone (axis ``a``, half-angle)."""
    e1 = np.cross(a, [0.0, 1.0, 0.0])
    if np.linalg.norm(e1) < 1e-9:
        e1 = np.cross(a, [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(a, e1)
    s = np.sqrt(max(1.0 - cos_alpha * cos_alpha, 0.0))
    rays = cos_alpha * a[None] + s * (np.cos(_ANG)[:, None] * e1 + np.sin(_ANG)[:, None] * e2)
    pix = rays @ np.asarray(K, dtype=float).T
    pts = pix[:, :2] / pix[:, 2:]
    m = pts.mean(axis=0)
    x = pts - m
    A = np.column_stack([x, np.ones(len(x))])
    sol = np.linalg.lstsq(A, (x * x).sum(axis=1), rcond=None)[0]
    cu, cv = sol[0] / 2, sol[1] / 2
    return np.array([cu + m[0], cv + m[1], np.sqrt(sol[2] + cu * cu + cv * cv)])


def eq1_circle(circle: Circle, K: np.ndarray, iterations: int = 3) -> Circle:
    """Convert a detected silhouette circle to the eq. (1) circle of the sphere; score kept.

    Parameters
    ----------
    circle : Circle
        Detected circle (pixels), a circle fitted to the sphere's silhouette.
    K : ndarray, shape (3, 3)
        Pinhole intrinsics with ``fx == fy`` (eq. (1)'s ``f`` is ``K[0, 0]``).
    iterations : int
        Fixed-point corrections of the cone for the ellipse-versus-circle difference.
    """
    K = np.asarray(K, dtype=float)
    Kinv = np.linalg.inv(K)
    target = np.array([circle.u, circle.v, circle.r], dtype=float)
    probe = target.copy()
    a, c = _cone(*probe, Kinv)
    for _ in range(iterations):
        probe = probe + (target - silhouette_circle(a, c, K))
        if probe[2] <= 0:
            break
        a, c = _cone(*probe, Kinv)
    s = np.sqrt(max(1.0 - c * c, 0.0))
    p = K @ a
    if p[2] <= 0 or s <= 0 or a[2] <= 0:
        return circle
    return Circle(float(p[0] / p[2]), float(p[1] / p[2]), float(K[0, 0] * s / a[2]), circle.score)
