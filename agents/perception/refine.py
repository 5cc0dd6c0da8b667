"""Sub-pixel refinement of rough circles: rim edge points along rays, then a robust circle fit.

Each rough circle (a Hough proposal) is refined by casting rays from its centre and taking, on each
ray, the sub-pixel position of the strongest radial intensity step within a band around the rough
radius. A circle is fitted to those rim points by iteratively re-weighted algebraic fits with a
shrinking inlier gate, then a few geometric Gauss-Newton steps on the inliers. Rays that hit an
occluder (a strut, a nearer node) or the sticker give outliers that the gate removes, which is what
keeps partially occluded and blurred spheres accurate. The fraction of rays that support the final
circle is its score. Everything is vectorised over all proposals of a frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from agents.perception.circle_fit import circle_residuals, fit_circles_algebraic, fit_circles_geometric

__all__ = ["RefineConfig", "coarse_fit", "refine_circles", "rim_points"]


@dataclass(frozen=True)
class RefineConfig:
    """Parameters of the rim search and fit.

    Attributes
    ----------
    rays, samples : int
        Rays cast from each centre, and samples along each ray within the band (second pass).
    coarse_rays, coarse_samples : int
        The same for the first pass (run on every proposal, so kept cheap).
    band : (float, float)
        First pass: the search band as fractions of the rough radius.
    fine_band : (float, float)
        Second pass, around the first fit.
    min_step : float
        Weakest accepted edge: absolute radial derivative in grey levels per pixel.
    tol : float
        Final inlier distance in pixels (plus ``tol_rel`` times the radius).
    tol_rel : float
        Final inlier distance relative to the radius.
    max_shift : float
        A refined centre may move at most this fraction of the rough radius.
    outer_frac : float
        On each ray the rim is the outermost local maximum of the radial step that reaches this
        fraction of the ray's strongest step.
    """

    rays: int = 64
    samples: int = 24
    coarse_rays: int = 32
    coarse_samples: int = 20
    band: tuple[float, float] = (0.6, 1.5)
    fine_band: tuple[float, float] = (0.85, 1.15)
    min_step: float = 3.0
    tol: float = 0.7
    tol_rel: float = 0.01
    max_shift: float = 0.6
    outer_frac: float = 0.1


def rim_points(
    image: np.ndarray,
    circles: np.ndarray,
    band: tuple[float, float],
    cfg: RefineConfig,
    *,
    rays: int | None = None,
    samples: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Rim point on each ray of each circle, between ``band[0] * r`` and ``band[1] * r``.

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, C), float32
        Grey or colour image (lightly smoothed).
    circles : ndarray, shape (N, 3)
        Rough circles (u, v, r).
    rays, samples : int, optional
        Override ``cfg.rays`` and ``cfg.samples``.

    Returns
    -------
    points : ndarray, shape (N, rays, 2)
        Sub-pixel rim point on each ray (rays in increasing angle).
    strength : ndarray, shape (N, rays)
        Edge strength (absolute radial derivative) at each rim point; 0 where not valid.
    """
    h, w = image.shape[:2]
    n = len(circles)
    n_rays = rays or cfg.rays
    n_samples = samples or cfg.samples
    ang = np.linspace(0.0, 2.0 * np.pi, n_rays, endpoint=False)
    frac = np.linspace(band[0], band[1], n_samples)
    rad = circles[:, 2, None] * frac[None, :]  # (N, S)
    step = rad[:, 1] - rad[:, 0]  # (N,)
    cos, sin = np.cos(ang), np.sin(ang)
    mx = circles[:, 0, None, None] + rad[:, None, :] * cos[None, :, None]  # (N, R, S)
    my = circles[:, 1, None, None] + rad[:, None, :] * sin[None, :, None]
    inside = ((mx >= 0) & (mx <= w - 1) & (my >= 0) & (my <= h - 1)).all(axis=2)
    prof = cv2.remap(
        image if image.dtype == np.float32 else image.astype(np.float32),
        mx.reshape(n * n_rays, n_samples).astype(np.float32),
        my.reshape(n * n_rays, n_samples).astype(np.float32),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    ).reshape(n, n_rays, n_samples, -1)
    # between samples i and i+1; on a colour image the channels' steps add (a grey sphere on a
    # brown floor can have almost no step in brightness on its shaded side)
    deriv = np.abs(np.diff(prof, axis=2)).sum(axis=3) / step[:, None, None]
    last = deriv.shape[2] - 1
    # the outermost local maximum with at least ``outer_frac`` of the ray's strongest step: a node's
    # rim is the outermost edge of the node, while its sticker's edges (often stronger) lie inside
    lm = np.ones(deriv.shape, dtype=bool)
    lm[..., 1:] &= deriv[..., 1:] >= deriv[..., :-1]
    lm[..., :-1] &= deriv[..., :-1] > deriv[..., 1:]
    strongest = deriv.max(axis=2, keepdims=True)
    cand = lm & (deriv >= np.maximum(cfg.outer_frac * strongest, cfg.min_step))
    k = last - np.argmax(cand[..., ::-1], axis=2)
    k = np.where(cand.any(axis=2), k, np.argmax(deriv, axis=2))
    peak = np.take_along_axis(deriv, k[..., None], axis=2)[..., 0]
    ym = np.take_along_axis(deriv, np.clip(k - 1, 0, last)[..., None], axis=2)[..., 0]
    yp = np.take_along_axis(deriv, np.clip(k + 1, 0, last)[..., None], axis=2)[..., 0]
    denom = ym - 2.0 * peak + yp
    interior = (k > 0) & (k < last) & (denom < 0)
    off = np.where(interior, 0.5 * (ym - yp) / np.where(interior, denom, -1.0), 0.0)
    dist = rad[:, :1] + (k + 0.5 + np.clip(off, -0.5, 0.5)) * step[:, None]  # (N, R)
    pts = np.stack([circles[:, 0, None] + dist * cos, circles[:, 1, None] + dist * sin], axis=2)
    valid = inside & (peak >= cfg.min_step)
    return pts, np.where(valid, peak, 0.0)


def _robust_fit(pts: np.ndarray, strength: np.ndarray, start: np.ndarray, gates: list[np.ndarray]):
    """Re-weighted algebraic fits with shrinking gates (each (N,) in pixels), from ``start``.

    Inliers are weighted by their squared edge strength: a shaded sphere's dark limb gives weak steps that
    sit inside the true rim (the shading falls off towards it), the lit limb strong, exact ones.
    """
    circles, ok = start.copy(), np.ones(len(start), dtype=bool)
    for gate in gates:
        inl = (strength > 0) & (np.abs(circle_residuals(pts, circles)) < gate[:, None])
        fit, fit_ok = fit_circles_algebraic(pts, np.where(inl, strength * strength, 0.0))
        circles = np.where(fit_ok[:, None], fit, circles)
        ok &= fit_ok
    return circles, ok


def coarse_fit(image: np.ndarray, rough: np.ndarray, cfg: RefineConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """First pass on every proposal: few rays, a wide band, a robust fit with shrinking gates.

    Returns (circles (N, 3), scores (N,), ok (N,)) as :func:`refine_circles`, the score over the
    coarse rays.
    """
    rough = np.asarray(rough, dtype=float).reshape(-1, 3)
    if len(rough) == 0:
        return rough.copy(), np.zeros(0), np.zeros(0, dtype=bool)
    r0 = rough[:, 2]
    pts, strength = rim_points(image, rough, cfg.band, cfg, rays=cfg.coarse_rays, samples=cfg.coarse_samples)
    tol = cfg.tol + cfg.tol_rel * r0 + 0.02 * r0
    circles, ok = _robust_fit(pts, strength, rough, [0.25 * r0, 0.12 * r0, tol])
    inl = (strength > 0) & (np.abs(circle_residuals(pts, circles)) < tol[:, None])
    shift = np.hypot(circles[:, 0] - rough[:, 0], circles[:, 1] - rough[:, 1])
    ok &= (inl.sum(axis=1) >= 4) & (shift <= cfg.max_shift * r0) & np.all(np.isfinite(circles), axis=1)
    ok &= circles[:, 2] > 0
    return circles, np.where(ok, inl.sum(axis=1) / cfg.coarse_rays, 0.0), ok


def refine_circles(image: np.ndarray, rough: np.ndarray, cfg: RefineConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Refine circles on ``image`` ((H, W) float32, lightly smoothed): a narrow band around each
    (already roughly right) circle, gated algebraic fits, then geometric steps on the inliers.

    Parameters
    ----------
    rough : ndarray, shape (N, 3)
        Circles within a few per cent of the rim (e.g. from :func:`coarse_fit`).

    Returns
    -------
    circles : ndarray, shape (N, 3)
        Refined (u, v, r).
    scores : ndarray, shape (N,)
        Fraction of all rays whose rim point lies within the final tolerance of the circle.
    ok : ndarray of bool, shape (N,)
        False where no consistent rim was found (fewer than 5 inliers, a degenerate fit, or a
        centre that moved more than a quarter radius).
    """
    rough = np.asarray(rough, dtype=float).reshape(-1, 3)
    if len(rough) == 0:
        return rough.copy(), np.zeros(0), np.zeros(0, dtype=bool)
    pts, strength = rim_points(image, rough, cfg.fine_band, cfg)
    tol = cfg.tol + cfg.tol_rel * rough[:, 2]
    circles, ok = _robust_fit(pts, strength, rough, [0.06 * rough[:, 2] + cfg.tol, 2.0 * tol, tol, tol])
    valid = strength > 0
    inl = valid & (np.abs(circle_residuals(pts, circles)) < tol[:, None])
    circles = fit_circles_geometric(pts, np.where(inl, strength * strength, 0.0), circles)
    inl = valid & (np.abs(circle_residuals(pts, circles)) < tol[:, None])
    shift = np.hypot(circles[:, 0] - rough[:, 0], circles[:, 1] - rough[:, 1])
    ok &= (inl.sum(axis=1) >= 5) & (shift <= 0.25 * rough[:, 2]) & (circles[:, 2] > 0)
    ok &= np.all(np.isfinite(circles), axis=1)
    scores = np.where(ok, inl.sum(axis=1) / cfg.rays, 0.0)
    return circles, scores, ok
