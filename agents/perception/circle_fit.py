"""Batched weighted circle fits: the algebraic (Kasa) fit and Gauss-Newton on geometric distances.

Pure numpy, vectorised over many circles at once (one per proposal), which is what keeps the
sub-pixel refinement of :mod:`agents.perception.refine` cheap. Points are (N, M, 2) arrays of pixel
coordinates (u, v), with per-point weights (N, M) (0 = not used); a circle is ``(u, v, r)``.
"""

from __future__ import annotations

import numpy as np

__all__ = ["fit_circles_algebraic", "fit_circles_geometric", "circle_residuals"]


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
    x = points - mean[:, None, :]  # centring keeps the normal equations well conditioned
    A = np.concatenate([x, np.ones(x.shape[:2] + (1,))], axis=2)  # (N, M, 3)
    b = (x * x).sum(axis=2)
    AtA = np.einsum("nmi,nm,nmj->nij", A, w, A)
    Atb = np.einsum("nmi,nm,nm->ni", A, w, b)
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
        JtJ = np.einsum("nmi,nm,nmj->nij", J, w, J)
        Jtr = np.einsum("nmi,nm,nm->ni", J, w, res)
        step, ok = _solve3(JtJ, -Jtr)
        new = est + step
        good = ok & np.all(np.isfinite(new), axis=1) & (new[:, 2] > 0)
        est = np.where(good[:, None], new, est)
        if np.abs(np.where(good[:, None], step, 0.0)).max(initial=0.0) < 1e-4:
            break
    return est
