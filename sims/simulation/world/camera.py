"""The pinhole camera model of the simulator: projection of nodes, field of view and occlusion.

The noiseless detection of a node is exactly Liu et al. 2024 eq. (1) inverted: the centre (u, v) is the
projection of the node centre and the radius is ``r = f r_0 / z_c`` with ``z_c`` the depth of the
centre in the camera frame and ``f = K[0, 0]``. The estimator's back-projection
``p = K^{-1} (f r_0 / r) [u, v, 1]^T`` then returns the true centre.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from decentral.observations import Pose

__all__ = ["default_K", "CameraSpec", "project_nodes", "silhouette_circle", "eq1_circle_from_silhouette", "visible_mask", "covered_fraction"]


def default_K(width: int = 1024, height: int = 768, f: float = 760.0) -> np.ndarray:
    """Pinhole intrinsics (3, 3) with focal length ``f`` px and the principal point at the image centre."""
    return np.array([[f, 0.0, width / 2.0], [0.0, f, height / 2.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class CameraSpec:
    """Intrinsics and sensing limits of one simulated camera.

    Attributes
    ----------
    K : ndarray, shape (3, 3)
        Pinhole intrinsics (``fx == fy`` expected for eq. (1)).
    width, height : int
        Image size [px].
    min_range, max_range : float
        Depth limits [m] of the camera frame's z for a node to be detected.
    min_radius : float
        Smallest circle radius [px] a detector still finds.
    """

    K: np.ndarray
    width: int = 1024
    height: int = 768
    min_range: float = 0.2
    max_range: float = 6.0
    min_radius: float = 4.0


def project_nodes(K: np.ndarray, cam_in_world: Pose, centres: np.ndarray, node_radius: float):
    """Project node centres into a camera.

    Parameters
    ----------
    K : ndarray, shape (3, 3)
    cam_in_world : Pose
        Pose of the camera frame c in the world frame W.
    centres : ndarray, shape (N, 3)
        Node centres in W [m].
    node_radius : float
        r_0 [m].

    Returns
    -------
    uvr : ndarray, shape (N, 3)
        Image centre (u, v) and radius r [px]; meaningless where ``depth <= 0``.
    depth : ndarray, shape (N,)
        z_c of each centre in c [m].
    """
    pc = (np.asarray(centres, dtype=float) - cam_in_world.p) @ cam_in_world.R  # rows: R^T (x - p)
    depth = pc[:, 2]
    safe = np.where(depth > 1e-9, depth, 1.0)
    hom = pc @ K.T / safe[:, None]
    r = K[0, 0] * node_radius / safe  # Liu et al. 2024 eq. (1) inverted: r = f r_0 / z_c
    return np.column_stack([hom[:, 0], hom[:, 1], r]), depth


def silhouette_circle(K: np.ndarray, centre_c, radius: float) -> tuple[float, float, float]:
    """Centre and equal-area radius [px] of the exact image of a sphere (an ellipse off the axis).

    Eq. (1)'s circle (projected centre, ``f r_0 / z_c``) is what the estimator models; the sphere's
    real silhouette is the conic of rays tangent to it, ``(c . d)^2 = (|c|^2 - r_0^2) |d|^2`` with
    ``d = K^{-1} [u, v, 1]^T``. Off the optical axis that ellipse is larger and its centre lies
    farther out than the projected centre (a few per cent of the radius at 20-30 deg): the
    difference is a model error a real detector faces too.

    Parameters
    ----------
    centre_c : (3,)
        Sphere centre in the camera frame, in front of it (``z_c > radius``).
    radius : float

    Returns
    -------
    (u, v, r) : the ellipse's centre and the radius of the circle of the same area.
    """
    c = np.asarray(centre_c, dtype=float)
    Kinv = np.linalg.inv(K)
    M = np.outer(c, c) - (c @ c - radius * radius) * np.eye(3)
    C = Kinv.T @ M @ Kinv
    A = C[:2, :2]
    x0 = np.linalg.solve(A, -C[:2, 2])
    p0 = np.array([x0[0], x0[1], 1.0])
    f = float(p0 @ C @ p0)
    lam = np.linalg.eigvalsh(A)
    r = (f * f / abs(lam[0] * lam[1])) ** 0.25
    return float(x0[0]), float(x0[1]), float(r)


def eq1_circle_from_silhouette(K: np.ndarray, su: float, sv: float, sr: float, radius: float,
                               iterations: int = 8) -> tuple[float, float, float]:
    """The eq. (1) circle (u, v, f r_0 / z_c) of the sphere whose exact silhouette is (su, sv, sr).

    Inverts :func:`silhouette_circle` by Newton's method on the sphere centre, started from the
    eq. (1) back-projection of the silhouette itself. A detector that fits a sphere's outline can
    pass its circle through this to remove eq. (1)'s off-axis bias before estimation.

    Returns
    -------
    (u, v, r) : the projected centre and ``f r_0 / z_c`` [px].
    """
    Kinv = np.linalg.inv(K)
    f = K[0, 0]
    target = np.array([su, sv, sr], dtype=float)

    def back(uvr):
        return Kinv @ np.array([uvr[0], uvr[1], 1.0]) * (f * radius / uvr[2])

    c = back(target)
    for _ in range(iterations):
        got = np.array(silhouette_circle(K, c, radius))
        err = got - target
        if np.max(np.abs(err)) < 1e-9:
            break
        J = np.empty((3, 3))
        h = 1e-6 * max(c[2], 1e-3)
        for i in range(3):
            dc = np.zeros(3)
            dc[i] = h
            J[:, i] = (np.array(silhouette_circle(K, c + dc, radius)) - got) / h
        c = c - np.linalg.solve(J, err)
    uvw = K @ c
    return float(uvw[0] / c[2]), float(uvw[1] / c[2]), float(f * radius / c[2])


def visible_mask(spec: CameraSpec, uvr: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """Nodes in front of the camera, within range, large enough, and whose whole circle is in the image."""
    u, v, r = uvr[:, 0], uvr[:, 1], uvr[:, 2]
    return (
        (depth >= spec.min_range)
        & (depth <= spec.max_range)
        & (r >= spec.min_radius)
        & (u - r >= 0.0)
        & (u + r <= spec.width)
        & (v - r >= 0.0)
        & (v + r <= spec.height)
    )


def _lens_area(d: np.ndarray, r1: np.ndarray, r2: np.ndarray) -> np.ndarray:
    """Area of the intersection of circles of radii r1, r2 whose centres are d apart."""
    d = np.maximum(d, 1e-12)
    out = np.zeros(np.broadcast(d, r1, r2).shape)
    inside = d <= np.abs(r1 - r2)
    out = np.where(inside, np.pi * np.minimum(r1, r2) ** 2, out)
    part = (d < r1 + r2) & ~inside
    c1 = np.clip((d**2 + r1**2 - r2**2) / (2 * d * r1), -1, 1)
    c2 = np.clip((d**2 + r2**2 - r1**2) / (2 * d * r2), -1, 1)
    k = (-d + r1 + r2) * (d + r1 - r2) * (d - r1 + r2) * (d + r1 + r2)
    lens = r1**2 * np.arccos(c1) + r2**2 * np.arccos(c2) - 0.5 * np.sqrt(np.clip(k, 0, None))
    return np.where(part, lens, out)


def covered_fraction(uvr: np.ndarray, depth: np.ndarray, candidates: np.ndarray | None = None,
                     targets: np.ndarray | None = None) -> np.ndarray:
    """Fraction of each node's image circle hidden by nearer nodes' circles.

    The covered area is approximated by the largest single overlap with a nearer circle (exact when
    one sphere occludes another, a lower bound when several do). ``candidates`` (N,) bool restricts
    the occluders to nodes in front of the camera (default: ``depth > 0``); ``targets`` (N,) bool
    restricts which nodes get a value (the others get 0; default: the candidates). Only pairs whose
    circles overlap are evaluated, so a large scene costs little more than its overlaps.

    Returns
    -------
    ndarray, shape (N,)
        Values in [0, 1]; 1 for a circle entirely behind a nearer one.
    """
    n = len(depth)
    if candidates is None:
        candidates = depth > 0
    if targets is None:
        targets = candidates
    frac = np.zeros(n)
    occ = np.flatnonzero(candidates)
    tgt = np.flatnonzero(targets & candidates)
    if len(occ) == 0 or len(tgt) == 0:
        return frac
    d = np.hypot(uvr[tgt, None, 0] - uvr[None, occ, 0], uvr[tgt, None, 1] - uvr[None, occ, 1])
    r_t = np.broadcast_to(uvr[tgt, None, 2], d.shape)
    r_o = np.broadcast_to(uvr[None, occ, 2], d.shape)
    pairs = (d < r_t + r_o) & (depth[None, occ] < depth[tgt, None])
    ti, oi = np.nonzero(pairs)
    if len(ti) == 0:
        return frac
    area = _lens_area(d[ti, oi], r_t[ti, oi], r_o[ti, oi])
    best = np.zeros(len(tgt))
    np.maximum.at(best, ti, area)
    frac[tgt] = best / (np.pi * np.maximum(uvr[tgt, 2], 1e-12) ** 2)
    return np.clip(frac, 0.0, 1.0)
