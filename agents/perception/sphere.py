"""From a sphere's image circle to the circle of seed 000 eq. (1) (centre projection, f r0 / z).

A sphere's silhouette in a pinhole image is an ellipse, not a circle: off the optical axis its best
circle is larger than ``f r0 / z`` and its centre is pushed outwards (5-8 % in radius at the edge of
a 1024 x 768 image with f = 760 px). The rim's rays form a cone around the ray to the sphere's centre
with half-angle ``asin(r0 / d)``: the unit rays of rim points lie on one plane ``a . x = cos(alpha)``.
Fitting that plane to rim points (sampled on the detected circle) recovers the centre direction
``a`` and ``sin(alpha)``, whence the eq. (1) circle: (u, v) = projection of ``a``,
r = f sin(alpha) / a_z, which makes ``K^-1 (f r0 / r) [u, v, 1]`` the sphere centre exactly.
"""

from __future__ import annotations

import numpy as np

from agents.perception.types import Circle

__all__ = ["eq1_circle"]


def eq1_circle(circle: Circle, K: np.ndarray, samples: int = 64) -> Circle:
    """Convert a detected silhouette circle to the eq. (1) circle of the sphere; score kept.

    Parameters
    ----------
    circle : Circle
        Detected circle (pixels).
    K : ndarray, shape (3, 3)
        Pinhole intrinsics with ``fx == fy`` (eq. (1)'s ``f`` is ``K[0, 0]``).
    """
    K = np.asarray(K, dtype=float)
    ang = np.linspace(0.0, 2.0 * np.pi, samples, endpoint=False)
    pix = np.stack([circle.u + circle.r * np.cos(ang), circle.v + circle.r * np.sin(ang), np.ones(samples)], axis=1)
    rays = pix @ np.linalg.inv(K).T
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    mean = rays.mean(axis=0)
    _, _, vt = np.linalg.svd(rays - mean)
    a = vt[-1] if vt[-1][2] > 0 else -vt[-1]
    c = float(np.clip(a @ mean, -1.0, 1.0))
    s = np.sqrt(max(1.0 - c * c, 0.0))
    p = K @ a
    if p[2] <= 0 or s <= 0:
        return circle
    return Circle(float(p[0] / p[2]), float(p[1] / p[2]), float(K[0, 0] * s / a[2]), circle.score)
