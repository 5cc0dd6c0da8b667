"""Batched weighted circle fits: the algebraic (Kasa) fit and Gauss-Newton on geometric distances.

Pure numpy, vectorised over many circles at once (one per proposal), which is what keeps the
sub-pixel refinement of :mod:`agents.perception.refine` cheap. Points are (N, M, 2) arrays of pixel
coordinates (u, v), with per-point weights (N, M) (0 = not used); a circle is ``(u, v, r)``.
"""

from __future__ import annotations

import numpy as np

__all__ = ["fit_circles_algebraic", "fit_circles_geometric", "circle_residuals", "fit_ellipses_direct", "ellipse_circles", "sampson_distances"]


def _solve3(A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Solve N 3x3 systems ``A x = b``; returns (x (N, 3), ok (N,)) with ok False where singular."""
    det = np.linalg.det(A)
    scale = np.abs(A).max(axis=(1, 2)) ** 3 + 1e-300
    ok = np.abs(det) > 1e-10 * scale
    safe = np.where(ok[:, None, None], A, np.eye(3)[None])
    x = np.linalg.solve(safe, b[..., None])[..., 0]
    return np.where(ok[:, None], x, 0.0), ok


def fit_circles_algebraic(points: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted algebraic fits (Kasa): minimise sum w (|x - c|^2 - r^2)^2 for each of N point sets.

    Parameters
    ----------
    points : ndarray, shape (N, M, 2)
    weights : ndarray, shape (N, M)
        Non-negative; a set needs at least three points of positive weight.

    Returns
    -------
    circles : ndarray, shape (N, 3)
        ``(u, v, r)``; zeros where the fit failed.
    ok : ndarray of bool, shape (N,)
    """
    w = np.asarray(weights, dtype=float)
    wsum = w.sum(axis=1)
    enough = (w > 0).sum(axis=1) >= 3
    mean = (points * w[..., None]).sum(axis=1) / np.maximum(wsum, 1e-300)[:, None]
    # centring keeps the normal equations well conditioned
    x, y = points[..., 0] - mean[:, 0, None], points[..., 1] - mean[:, 1, None]
    b = x * x + y * y
    # the normal equations of rows A = (x, y, 1), right-hand side b, summed directly: the batched
    # matmul of (N, 3, M) by (N, M, 3) cost 4x more for the many small sets of a frame
    wx, wy = w * x, w * y
    sxx, sxy, syy = (wx * x).sum(axis=1), (wx * y).sum(axis=1), (wy * y).sum(axis=1)
    sx, sy = wx.sum(axis=1), wy.sum(axis=1)
    AtA = np.stack([np.stack([sxx, sxy, sx], axis=1), np.stack([sxy, syy, sy], axis=1),
                    np.stack([sx, sy, wsum], axis=1)], axis=1)
    Atb = np.stack([(wx * b).sum(axis=1), (wy * b).sum(axis=1), (w * b).sum(axis=1)], axis=1)
    sol, ok = _solve3(AtA, Atb)
    cu, cv = sol[:, 0] / 2.0, sol[:, 1] / 2.0
    r2 = sol[:, 2] + cu * cu + cv * cv
    ok &= enough & np.isfinite(r2) & (r2 > 0)
    circles = np.column_stack([cu + mean[:, 0], cv + mean[:, 1], np.sqrt(np.where(ok, r2, 1.0))])
    return np.where(ok[:, None], circles, 0.0), ok


def circle_residuals(points: np.ndarray, circles: np.ndarray) -> np.ndarray:
    """Signed geometric residuals |x - c| - r, shape (N, M), of points (N, M, 2) to circles (N, 3)."""
    d = points - circles[:, None, :2]
    return np.hypot(d[..., 0], d[..., 1]) - circles[:, None, 2]


def fit_circles_geometric(
    points: np.ndarray, weights: np.ndarray, start: np.ndarray, iterations: int = 4
) -> np.ndarray:
    """Refine circles ``start`` (N, 3) by weighted Gauss-Newton on the geometric residuals.

    The algebraic fit is biased towards small radii on short, noisy arcs; a few geometric steps
    remove that bias. Circles whose step would degenerate keep their previous value.
    """
    est = np.asarray(start, dtype=float).copy()
    w = np.asarray(weights, dtype=float)
    for _ in range(iterations):
        d = points - est[:, None, :2]
        dist = np.maximum(np.hypot(d[..., 0], d[..., 1]), 1e-9)
        res = dist - est[:, None, 2]
        J = np.stack([-d[..., 0] / dist, -d[..., 1] / dist, -np.ones_like(dist)], axis=2)
        Jw = (J * w[..., None]).transpose(0, 2, 1)
        JtJ = np.matmul(Jw, J)
        Jtr = np.matmul(Jw, res[..., None])[..., 0]
        step, ok = _solve3(JtJ, -Jtr)
        new = est + step
        good = ok & np.all(np.isfinite(new), axis=1) & (new[:, 2] > 0)
        est = np.where(good[:, None], new, est)
        if np.abs(np.where(good[:, None], step, 0.0)).max(initial=0.0) < 1e-4:
            break
    return est


def fit_ellipses_direct(points: np.ndarray, weights: np.ndarray, centre: np.ndarray, scale: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Weighted direct least-squares ellipse fits (Fitzgibbon, in Halir and Flusser's stable form) [1]_.

    Parameters
    ----------
    points : ndarray, shape (N, M, 2)
    weights : ndarray, shape (N, M)
        Non-negative; a set needs at least six points of positive weight.
    centre, scale : ndarray, shapes (N, 2) and (N,)
        Each set is fitted in coordinates ``(x - centre) / scale`` (conditioning); the returned
        conics are in those normalised coordinates.

    Returns
    -------
    conics : ndarray, shape (N, 6)
        ``(A, B, C, D, E, F)`` of ``A x^2 + B x y + C y^2 + D x + E y + F = 0`` (normalised
        coordinates); zeros where the fit failed.
    ok : ndarray of bool, shape (N,)

    References
    ----------
    .. [1] R. Halir, J. Flusser, "Numerically stable direct least squares fitting of ellipses",
       WSCG 1998.
    """
    w = np.asarray(weights, dtype=float)
    x = (points[..., 0] - centre[:, None, 0]) / scale[:, None]
    y = (points[..., 1] - centre[:, None, 1]) / scale[:, None]
    D1 = np.stack([x * x, x * y, y * y], axis=2)  # (N, M, 3)
    D2 = np.stack([x, y, np.ones_like(x)], axis=2)
    S1 = np.einsum("nmi,nm,nmj->nij", D1, w, D1)
    S2 = np.einsum("nmi,nm,nmj->nij", D1, w, D2)
    S3 = np.einsum("nmi,nm,nmj->nij", D2, w, D2)
    enough = (w > 0).sum(axis=1) >= 6
    det3 = np.linalg.det(S3)
    ok = enough & (np.abs(det3) > 1e-12 * (np.abs(S3).max(axis=(1, 2)) ** 3 + 1e-300))
    S3s = np.where(ok[:, None, None], S3, np.eye(3)[None])
    T = -np.linalg.solve(S3s, np.transpose(S2, (0, 2, 1)))  # (N, 3, 3)
    M = S1 + S2 @ T
    Cinv = np.array([[0.0, 0.0, 0.5], [0.0, -1.0, 0.0], [0.5, 0.0, 0.0]])
    M = Cinv[None] @ M
    M = np.where(np.isfinite(M).all(axis=(1, 2))[:, None, None] & ok[:, None, None], M, np.eye(3)[None])
    _, vecs = np.linalg.eig(M)
    vecs = np.real(vecs)  # (N, 3, 3), columns
    cond = 4.0 * vecs[:, 0, :] * vecs[:, 2, :] - vecs[:, 1, :] ** 2  # (N, 3): > 0 for the ellipse
    j = np.argmax(cond, axis=1)
    a1 = vecs[np.arange(len(j)), :, j]  # (N, 3)
    ok &= cond[np.arange(len(j)), j] > 0
    a2 = np.einsum("nij,nj->ni", T, a1)
    conics = np.concatenate([a1, a2], axis=1)
    return np.where(ok[:, None], conics, 0.0), ok


def ellipse_circles(conics: np.ndarray, centre: np.ndarray, scale: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centre and equal-area radius of normalised ellipse conics (from :func:`fit_ellipses_direct`).

    Returns
    -------
    circles : ndarray, shape (N, 3)
        ``(u, v, sqrt(a b))`` in image pixels: the ellipse's centre and the radius of the circle of
        its area (the convention of a sphere's silhouette circle).
    ratio : ndarray, shape (N,)
        Major over minor semi-axis (>= 1).
    major : ndarray, shape (N, 2)
        Unit direction of the major axis (image axes).
    ok : ndarray of bool, shape (N,)
        False for degenerate conics.
    """
    A, B, C, D, E, F = conics.T
    det = 4.0 * A * C - B * B
    ok = det > 1e-12
    safe = np.where(ok, det, 1.0)
    x0 = (B * E - 2.0 * C * D) / safe
    y0 = (B * D - 2.0 * A * E) / safe
    F0 = A * x0 * x0 + B * x0 * y0 + C * y0 * y0 + D * x0 + E * y0 + F
    half = np.sqrt(np.maximum((A - C) ** 2 + B * B, 0.0))
    l1, l2 = 0.5 * (A + C - half), 0.5 * (A + C + half)  # eigenvalues of [[A, B/2], [B/2, C]]
    ok &= (l1 * l2 > 0) & (F0 * l1 < 0)
    prod = np.where(ok, l1 * l2, 1.0)
    r = np.where(ok, (F0 * F0 / prod) ** 0.25, 0.0) * scale
    ratio = np.where(ok, np.sqrt(np.abs(np.maximum(np.abs(l1), np.abs(l2)) / np.maximum(np.minimum(np.abs(l1), np.abs(l2)), 1e-300))), np.inf)
    circles = np.column_stack([x0 * scale + centre[:, 0], y0 * scale + centre[:, 1], r])
    # the major axis is the eigenvector of the eigenvalue of smaller magnitude
    small = np.where(np.abs(l1) <= np.abs(l2), l1, l2)
    major = np.column_stack([0.5 * B, small - A])  # (A - l) x + B/2 y = 0
    alt = np.column_stack([small - C, 0.5 * B])
    major = np.where((np.hypot(*major.T) >= np.hypot(*alt.T))[:, None], major, alt)
    major /= np.maximum(np.hypot(major[:, 0], major[:, 1]), 1e-300)[:, None]
    return np.where(ok[:, None], circles, 0.0), ratio, major, ok & np.all(np.isfinite(circles), axis=1)


def sampson_distances(points: np.ndarray, conics: np.ndarray, centre: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """First-order geometric distances (pixels), shape (N, M), of points (N, M, 2) to normalised conics."""
    x = (points[..., 0] - centre[:, None, 0]) / scale[:, None]
    y = (points[..., 1] - centre[:, None, 1]) / scale[:, None]
    A, B, C, D, E, F = (conics[:, i, None] for i in range(6))
    q = A * x * x + B * x * y + C * y * y + D * x + E * y + F
    gx, gy = 2.0 * A * x + B * y + D, B * x + 2.0 * C * y + E
    return np.abs(q) / np.maximum(np.hypot(gx, gy), 1e-300) * scale[:, None]
