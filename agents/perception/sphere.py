"""From a sphere's image circle to the circle of Liu et al. 2024 eq. (1) (centre projection, f r0 / z).

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

from agents.perception.circle_fit import fit_circles_algebraic
from agents.perception.types import Circle

__all__ = ["eq1_circle", "eq1_circles", "silhouette_circle"]

_ANG = np.linspace(0.0, 2.0 * np.pi, 64, endpoint=False)
_COS, _SIN = np.cos(_ANG), np.sin(_ANG)


def _cones(circles: np.ndarray, Kinv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cone (unit axis (N, 3), cos of half-angle (N,)) whose rays best fit each circle's rim rays."""
    pix = np.stack([circles[:, 0, None] + circles[:, 2, None] * _COS, circles[:, 1, None] + circles[:, 2, None] * _SIN,
                    np.ones((len(circles), len(_ANG)))], axis=2)  # (N, 64, 3)
    rays = pix @ Kinv.T
    rays /= np.linalg.norm(rays, axis=2, keepdims=True)
    mean = rays.mean(axis=1)
    x = rays - mean[:, None, :]
    # the plane's normal: the eigenvector of the scatter matrix with the smallest eigenvalue
    _, vecs = np.linalg.eigh(np.einsum("nmi,nmj->nij", x, x))
    a = vecs[:, :, 0]
    a = np.where(a[:, 2:] > 0, a, -a)
    return a, np.clip(np.einsum("ni,ni->n", a, mean), -1.0, 1.0)


def _silhouettes(a: np.ndarray, cos_alpha: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Algebraic best circles (N, 3) through the exact silhouettes of cones (axes (N, 3), cosines (N,))."""
    e1 = np.cross(a, [0.0, 1.0, 0.0])
    flat = np.linalg.norm(e1, axis=1) < 1e-9
    if flat.any():
        e1[flat] = np.cross(a[flat], [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(a, e1)
    s = np.sqrt(np.maximum(1.0 - cos_alpha * cos_alpha, 0.0))
    rays = (cos_alpha[:, None, None] * a[:, None, :]
            + s[:, None, None] * (_COS[None, :, None] * e1[:, None, :] + _SIN[None, :, None] * e2[:, None, :]))
    pix = rays @ np.asarray(K, dtype=float).T
    pts = pix[..., :2] / pix[..., 2:]
    circles, _ = fit_circles_algebraic(pts, np.ones(pts.shape[:2]))
    return circles


def silhouette_circle(a: np.ndarray, cos_alpha: float, K: np.ndarray) -> np.ndarray:
    """Algebraic best circle (u, v, r) through the exact silhouette of the cone (axis ``a``, half-angle)."""
    return _silhouettes(np.asarray(a, dtype=float)[None], np.array([float(cos_alpha)]), K)[0]


def eq1_circles(circles: np.ndarray, K: np.ndarray, iterations: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Batched :func:`eq1_circle`: detected silhouette circles (N, 3) -> eq. (1) circles (N, 3).

    Returns
    -------
    eq1 : ndarray, shape (N, 3)
        (u, v, r) of each sphere's eq. (1) circle; the input circle where the cone is degenerate.
    ok : ndarray of bool, shape (N,)
        False where the input circle was returned unchanged.
    """
    K = np.asarray(K, dtype=float)
    Kinv = np.linalg.inv(K)
    target = np.asarray(circles, dtype=float).reshape(-1, 3)
    if len(target) == 0:
        return target.copy(), np.zeros(0, dtype=bool)
    probe = target.copy()
    a, c = _cones(probe, Kinv)
    live = np.ones(len(target), dtype=bool)
    for _ in range(iterations):
        step = probe + (target - _silhouettes(a, c, K))
        live &= step[:, 2] > 0  # a probe that would turn inside out stops at its last cone
        probe = np.where(live[:, None], step, probe)
        if not live.any():
            break
        a2, c2 = _cones(probe, Kinv)
        a, c = np.where(live[:, None], a2, a), np.where(live, c2, c)
    s = np.sqrt(np.maximum(1.0 - c * c, 0.0))
    p = a @ K.T
    ok = (p[:, 2] > 0) & (s > 0) & (a[:, 2] > 0)
    pz = np.where(ok, p[:, 2], 1.0)
    eq1 = np.column_stack([p[:, 0] / pz, p[:, 1] / pz, K[0, 0] * s / np.where(ok, a[:, 2], 1.0)])
    return np.where(ok[:, None], eq1, target), ok


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
    eq1, _ = eq1_circles(np.array([[circle.u, circle.v, circle.r]]), K, iterations)
    return Circle(float(eq1[0, 0]), float(eq1[0, 1]), float(eq1[0, 2]), circle.score)
