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
from typing import Callable

import cv2
import numpy as np

from agents.perception.circle_fit import (
    circle_residuals,
    ellipse_circles,
    fit_circles_algebraic,
    fit_circles_geometric,
    fit_ellipses_direct,
    sampson_distances,
)

__all__ = ["RefineConfig", "coarse_fit", "coarse_score", "refine_circles", "rim_points"]


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
    max_axis_ratio : float
        Second pass: largest major/minor axis ratio of the ellipse fit (1: circles only).
    ellipse_gate : float
        Second pass: rim points within this fraction of the radius (plus ``tol``) of the circle
        seed the ellipse fit.
    max_axis_turn_deg : float
        Second pass: an elongated ellipse is kept only if its major axis points within this angle
        of the image centre (a sphere's image is elongated radially from the principal point).
    min_focal_px : float
        Second pass: the shortest focal length (px) assumed; an ellipse at distance d from the
        image centre may be elongated at most ``sqrt(1 + (d / min_focal_px)^2)`` (+ 0.03). 500 px
        allows a 92 deg horizontal field of view at 1024 px.
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
    max_axis_ratio: float = 1.5
    ellipse_gate: float = 0.12
    max_axis_turn_deg: float = 20.0
    min_focal_px: float = 500.0


def _sample(image: np.ndarray, mx: np.ndarray, my: np.ndarray) -> np.ndarray:
    """Bilinear samples of ``image`` at float32 maps (P, S), shape (P, S) or (P, S, C); edges replicated.

    ``cv2.remap`` takes maps of fewer than 2^15 rows, so long maps are sampled in blocks.
    """
    rows = 32000
    if len(mx) <= rows:
        return cv2.remap(image, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return np.concatenate([cv2.remap(image, mx[i:i + rows], my[i:i + rows], cv2.INTER_LINEAR,
                                     borderMode=cv2.BORDER_REPLICATE) for i in range(0, len(mx), rows)])


def _radial_steps(image: np.ndarray, circles: np.ndarray, radii: np.ndarray, n_rays: int):
    """Absolute radial intensity steps along rays from each circle's centre.

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, C), float32
    circles : ndarray, shape (N, 3)
        Centres (u, v) and radii (unused here) of the hypotheses.
    radii : ndarray, shape (N, S)
        Increasing sample distances from the centre along every ray (px).
    n_rays : int
        Rays per centre, at equally spaced angles from 0.

    Returns
    -------
    deriv : ndarray, shape (N, n_rays, S - 1), float32
        Step between samples i and i + 1 per pixel of distance (on a colour image the channels' steps
        add: a grey sphere on a brown floor can have almost no step in brightness).
    inside : ndarray of bool, shape (N, n_rays)
        The whole ray lies inside the image.
    cos, sin : ndarray, shape (n_rays,)
    """
    h, w = image.shape[:2]
    n, n_samples = radii.shape
    ang = np.linspace(0.0, 2.0 * np.pi, n_rays, endpoint=False)
    cos, sin = np.cos(ang), np.sin(ang)
    # sample positions in float32 (what remap takes); a ray lies inside the image iff both its ends do
    c32, rad32 = circles.astype(np.float32), radii.astype(np.float32)
    cos32, sin32 = cos.astype(np.float32), sin.astype(np.float32)
    mx = c32[:, 0, None, None] + rad32[:, None, :] * cos32[None, :, None]  # (N, R, S)
    my = c32[:, 1, None, None] + rad32[:, None, :] * sin32[None, :, None]
    ends_x, ends_y = mx[:, :, [0, -1]], my[:, :, [0, -1]]
    inside = ((ends_x >= 0) & (ends_x <= w - 1) & (ends_y >= 0) & (ends_y <= h - 1)).all(axis=2)
    img = image if image.dtype == np.float32 else image.astype(np.float32)
    ch = 1 if img.ndim == 2 else img.shape[2]
    prof = _sample(img, mx.reshape(n * n_rays, n_samples), my.reshape(n * n_rays, n_samples)).reshape(
        n * n_rays, n_samples * ch)
    deriv = cv2.absdiff(prof[:, ch:], prof[:, :-ch])
    if ch > 1:
        deriv = cv2.transform(deriv.reshape(n * n_rays, n_samples - 1, ch), np.ones((1, ch), np.float32))
    step = np.diff(radii, axis=1).astype(np.float32)  # (N, S - 1)
    deriv = deriv.reshape(n, n_rays, n_samples - 1) / step[:, None, :]
    return deriv, inside, cos, sin


def _local_maxima(deriv: np.ndarray) -> np.ndarray:
    """Bool mask of the local maxima of ``deriv`` along its last axis (plateaus: their first sample)."""
    lm = np.ones(deriv.shape, dtype=bool)
    lm[..., 1:] &= deriv[..., 1:] >= deriv[..., :-1]
    lm[..., :-1] &= deriv[..., :-1] > deriv[..., 1:]
    return lm


def _subsample(deriv: np.ndarray, k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Peak value and sub-sample offset (-0.5..0.5, a parabola through 3 samples) at indices ``k`` (..., C)."""
    last = deriv.shape[-1] - 1
    kk = np.clip(k, 0, last)
    peak = np.take_along_axis(deriv, kk, axis=-1)
    ym = np.take_along_axis(deriv, np.clip(kk - 1, 0, last), axis=-1)
    yp = np.take_along_axis(deriv, np.clip(kk + 1, 0, last), axis=-1)
    denom = ym - 2.0 * peak + yp
    interior = (kk > 0) & (kk < last) & (denom < 0)
    off = np.where(interior, 0.5 * (ym - yp) / np.where(interior, denom, -1.0), 0.0)
    return peak, np.clip(off, -0.5, 0.5)


def _ray_points(circles, cos, sin, dist):
    """Points (N, R, C, 2) at distances ``dist`` (N, R, C) along the rays of each circle."""
    return np.stack([circles[:, 0, None, None] + dist * cos[None, :, None],
                     circles[:, 1, None, None] + dist * sin[None, :, None]], axis=3)


def _edge_nearest(deriv: np.ndarray, cand: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per ray, the qualifying edge (``cand``) nearest the sample index ``target`` (N,).

    Returns its index (N, R, 1) and its distance from ``target`` in samples (N, R); rays without a
    qualifying edge get a distance larger than any index.
    """
    last = deriv.shape[2] - 1
    idx = np.arange(last + 1)
    gap = np.where(cand, np.abs(idx[None, None, :] - np.asarray(target)[:, None, None]), last + 1)
    k = np.argmin(gap, axis=2)[..., None]
    return k, np.take_along_axis(gap, k, axis=2)[..., 0]


def rim_points(
    image: np.ndarray,
    circles: np.ndarray,
    band: tuple[float, float],
    cfg: RefineConfig,
    *,
    rays: int | None = None,
    samples: int | None = None,
    candidates: int = 1,
    nearest: bool = False,
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
    candidates : int
        With 1, the rim is the outermost qualifying edge of each ray; with C > 1, the C outermost
        qualifying edges are returned (outermost first) and the fit chooses among them.
    nearest : bool
        Take the qualifying edge nearest the circle ``r`` instead of the outermost (for circles
        whose radius is already known to a few per cent: floor texture or a shadow just outside a
        node's rim would otherwise win over the rim).

    Returns
    -------
    points : ndarray, shape (N, rays, 2), or (N, rays, C, 2)
        Sub-pixel rim point on each ray (rays in increasing angle).
    strength : ndarray, shape (N, rays) or (N, rays, C)
        Edge strength (absolute radial derivative) at each rim point; 0 where not valid.
    """
    n_rays = rays or cfg.rays
    n_samples = samples or cfg.samples
    frac = np.linspace(band[0], band[1], n_samples)
    rad = circles[:, 2, None] * frac[None, :]  # (N, S)
    step = rad[:, 1] - rad[:, 0]  # (N,)
    deriv, inside, cos, sin = _radial_steps(image, circles, rad, n_rays)
    last = deriv.shape[2] - 1
    # the outermost local maximum with at least ``outer_frac`` of the ray's strongest step: a node's
    # rim is the outermost edge of the node, while its sticker's edges (often stronger) lie inside
    strongest = deriv.max(axis=2, keepdims=True)
    cand = _local_maxima(deriv) & (deriv >= np.maximum(cfg.outer_frac * strongest, cfg.min_step))
    if nearest:
        target = (1.0 - band[0]) / (band[1] - band[0]) * (n_samples - 1) - 0.5  # the step index at r
        k, _ = _edge_nearest(deriv, cand, np.full(len(circles), target))
        none = ~cand.any(axis=2)
        k[..., 0] = np.where(none, np.argmax(deriv, axis=2), k[..., 0])
    elif candidates == 1:
        # the last qualifying index as the maximum of (index + 1) over the qualifying samples (0: none;
        # one uint8 pass instead of an argmax over a reversed view); rays with none fall back to
        # their strongest step
        kk1 = (cand.view(np.uint8) * np.arange(1, last + 2, dtype=np.uint8 if last < 255 else np.intp)).max(axis=2)
        k = kk1.astype(np.intp) - 1
        none = kk1 == 0
        if none.any():
            k[none] = np.argmax(deriv[none], axis=1)
        k = k[..., None]
    else:
        # the ``candidates`` outermost qualifying maxima, outermost first (-1: none)
        count = np.cumsum(cand[..., ::-1], axis=2)[..., ::-1]  # qualifying maxima at or beyond each sample
        ks = [np.where((m := cand & (count == j + 1)).any(axis=2), np.argmax(m, axis=2), -1) for j in range(candidates)]
        k = np.stack(ks, axis=2)
        k[..., 0] = np.where(k[..., 0] < 0, np.argmax(deriv, axis=2), k[..., 0])
    peak, off = _subsample(deriv, k)
    dist = rad[:, :1, None] + (np.clip(k, 0, last) + 0.5 + off) * step[:, None, None]  # (N, R, C)
    pts = _ray_points(circles, cos, sin, dist)
    valid = inside[..., None] & (peak >= cfg.min_step) & (k >= 0)
    strength = np.where(valid, peak, 0.0)
    if candidates == 1 or nearest:
        return pts[:, :, 0], strength[:, :, 0]
    return pts, strength


def _nearest(pts: np.ndarray, strength: np.ndarray, circles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per ray, the candidate (of (N, R, C)) nearest to each circle (N, 3): points (N, R, 2), strength (N, R)."""
    d = pts - circles[:, None, None, :2]
    res = np.abs(np.hypot(d[..., 0], d[..., 1]) - circles[:, None, None, 2])
    j = np.argmin(np.where(strength > 0, res, np.inf), axis=2)[..., None]
    return np.take_along_axis(pts, j[..., None], axis=2)[:, :, 0], np.take_along_axis(strength, j, axis=2)[..., 0]


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
    return coarse_score(pts, strength, rough, rough, r0, [0.25 * r0, 0.12 * r0], cfg)


def coarse_score(pts: np.ndarray, strength: np.ndarray, start: np.ndarray, rough: np.ndarray, r0: np.ndarray,
                 gates: list, cfg: RefineConfig, edges: Callable | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fit circles robustly to coarse-ray rim points and score them (the last step of every coarse pass).

    ``pts`` (N, R, 2) and ``strength`` (N, R) are the rim points, ``start`` (N, 3) the circles the fit
    starts from, ``gates`` its first shrinking gates (the coarse tolerance ``tol + tol_rel r0 + 0.02 r0``
    is the last), ``rough`` (N, 3) the proposals a circle may not move far from (``max_shift r0``).
    ``edges(pts, circles)``, if given, is a further (N, R) condition on the inliers. Returns (circles,
    scores over the coarse rays, ok) as :func:`coarse_fit`.
    """
    tol = cfg.tol + cfg.tol_rel * r0 + 0.02 * r0
    circles, ok = _robust_fit(pts, strength, start, [*gates, tol])
    inl = (strength > 0) & (np.abs(circle_residuals(pts, circles)) < tol[:, None])
    if edges is not None:
        inl &= edges(pts, circles)
    shift = np.hypot(circles[:, 0] - rough[:, 0], circles[:, 1] - rough[:, 1])
    ok &= (inl.sum(axis=1) >= 4) & (shift <= cfg.max_shift * r0) & np.all(np.isfinite(circles), axis=1)
    ok &= circles[:, 2] > 0
    return circles, np.where(ok, inl.sum(axis=1) / cfg.coarse_rays, 0.0), ok


def refine_circles(image: np.ndarray, rough: np.ndarray, cfg: RefineConfig, *, nearest: bool = False,
                   ellipse_margin: float = 0.0, edges: Callable | None = None, min_step: float | None = None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Refine circles on ``image`` ((H, W) float32, lightly smoothed): a narrow band around each
    (already roughly right) circle, gated algebraic fits, then geometric steps on the inliers.

    A sphere off the optical axis images as an ellipse (axis ratio about ``1 / cos`` of the
    off-axis angle: 1.17 at 31 deg), whose rim strays from any circle by more than the inlier
    tolerance once the node is large; a circle fitted with a tight gate then holds to part of the
    rim and comes out too large or too small. So an ellipse is also fitted (direct least squares on
    the rim points near the circle, then re-gated on Sampson distances); where it explains more
    rays than the circle, the circle returned is the ellipse's centre and equal-area radius
    ``sqrt(a b)`` (the convention of a silhouette circle).

    Parameters
    ----------
    rough : ndarray, shape (N, 3)
        Circles within a few per cent of the rim (e.g. from :func:`coarse_fit`).
    nearest : bool
        On each ray the edge nearest the rough circle, else the strongest (:func:`rim_points`).
    ellipse_margin : float
        Share of the rays by which an ellipse must fit more rays than the circle to replace it.
    edges : callable, optional
        ``edges(pts (N, R, 2), circles (N, 3))`` -> (N, R) bool: a further condition on the inliers
        (the rim detectors: the gradient points along the ray).
    min_step : float, optional
        Least median edge step of the supporting rays (a rim is an edge: a smooth bright patch of
        floor can be round, with radial gradients of a grey level per pixel).

    Returns
    -------
    circles : ndarray, shape (N, 3)
        Refined (u, v, r).
    scores : ndarray, shape (N,)
        Fraction of all rays whose rim point lies within the final tolerance of the circle (of the
        ellipse, where that was kept).
    ok : ndarray of bool, shape (N,)
        False where no consistent rim was found (fewer than 5 inliers, a degenerate fit, or a
        centre that moved more than a quarter radius).
    """
    rough = np.asarray(rough, dtype=float).reshape(-1, 3)
    if len(rough) == 0:
        return rough.copy(), np.zeros(0), np.zeros(0, dtype=bool)
    pts, strength = rim_points(image, rough, cfg.fine_band, cfg, nearest=nearest)
    r0 = rough[:, 2]
    tol = cfg.tol + cfg.tol_rel * r0
    circles, ok = _robust_fit(pts, strength, rough, [0.06 * r0 + cfg.tol, 2.0 * tol, tol, tol])
    valid = strength > 0
    inl = valid & (np.abs(circle_residuals(pts, circles)) < tol[:, None])
    circles = fit_circles_geometric(pts, np.where(inl, strength * strength, 0.0), circles)
    inl = valid & (np.abs(circle_residuals(pts, circles)) < tol[:, None])
    if cfg.max_axis_ratio > 1.0:
        h, w = image.shape[:2]
        circles, inl = _ellipse_stage(pts, strength, circles, inl, tol, cfg, ((w - 1) / 2.0, (h - 1) / 2.0),
                                      ellipse_margin)
    if edges is not None:
        inl &= edges(pts, circles)
    shift = np.hypot(circles[:, 0] - rough[:, 0], circles[:, 1] - rough[:, 1])
    ok &= (inl.sum(axis=1) >= 5) & (shift <= 0.25 * r0) & (circles[:, 2] > 0)
    ok &= np.all(np.isfinite(circles), axis=1)
    if min_step is not None:
        ranked = -np.sort(-np.where(inl, strength, 0.0), axis=1)  # supporting steps first, largest first
        median = ranked[np.arange(len(ranked)), np.maximum(inl.sum(axis=1) // 2, 0)]
        ok &= median >= min_step
    scores = np.where(ok, inl.sum(axis=1) / cfg.rays, 0.0)
    return circles, scores, ok


def _ellipse_stage(pts, strength, circles, inl, tol, cfg: RefineConfig, image_centre, margin: float = 0.0):
    """Replace circles by ellipse centres / equal-area radii where an ellipse fits more rays
    (more by at least ``margin`` of the rays: 0 for the default detector, see
    :class:`agents.perception.rim_refine.RimRefineConfig` ``ellipse_margin``)."""
    valid = strength > 0
    w2 = strength * strength
    centre, scale = circles[:, :2].copy(), np.maximum(circles[:, 2], 1.0)
    near = valid & (np.abs(circle_residuals(pts, circles)) < (cfg.ellipse_gate * scale + tol)[:, None])
    conics, eok = fit_ellipses_direct(pts, np.where(near, w2, 0.0), centre, scale)
    for gate in (2.0 * tol, tol):
        einl = valid & (sampson_distances(pts, conics, centre, scale) < gate[:, None])
        again, aok = fit_ellipses_direct(pts, np.where(einl, w2, 0.0), centre, scale)
        conics, eok = np.where(aok[:, None], again, conics), eok & aok
    ec, ratio, major, cok = ellipse_circles(conics, centre, scale)
    einl = valid & (sampson_distances(pts, conics, centre, scale) < tol[:, None])
    moved = np.hypot(ec[:, 0] - circles[:, 0], ec[:, 1] - circles[:, 1])
    # a sphere's ellipse points its major axis at the principal point (taken as the image centre)
    radial = ec[:, :2] - np.asarray(image_centre, dtype=float)[None]
    radial /= np.maximum(np.hypot(radial[:, 0], radial[:, 1]), 1e-9)[:, None]
    aligned = (ratio <= 1.03) | (np.abs(np.einsum("ni,ni->n", major, radial)) >= np.cos(np.radians(cfg.max_axis_turn_deg)))
    # and no more elongated than a sphere can look there: ratio ~ 1 / cos(off-axis angle), the angle
    # at most atan(d / f) for a focal length f of at least ``min_focal_px`` (the distance d from the
    # image centre); partly hidden rims otherwise pass for ellipses
    d = np.hypot(ec[:, 0] - image_centre[0], ec[:, 1] - image_centre[1])
    possible = np.minimum(cfg.max_axis_ratio, np.sqrt(1.0 + (d / cfg.min_focal_px) ** 2) + 0.03)
    better = (eok & cok & (ratio <= possible) & aligned & (einl.sum(axis=1) > inl.sum(axis=1) + margin * pts.shape[1])
              & (moved <= 0.2 * scale) & (np.abs(ec[:, 2] / scale - 1.0) <= 0.2))
    return np.where(better[:, None], ec, circles), np.where(better[:, None], einl, inl)
