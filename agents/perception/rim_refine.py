"""The rim search of the opt-in rim detector (:mod:`agents.perception.rim`): rim votes, radial edges, a robust fit.

The default detector's refinement is :mod:`agents.perception.refine`; this module is its variant
that finds a sphere's rim rather than its tag (the circle fit helpers are shared). Differences:
the first pass votes on the rim radius along rays (:func:`rim_votes`) and, where that rim is weak,
searches three-edge circles (:func:`rim_search`); only edges whose gradient is radial support a
circle (:func:`radial_edges`); the fine pass can take the edge nearest the rough circle; a rim needs
a median step of ``min_rim_step``; the ellipse needs ``ellipse_margin`` more rays than the circle.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from agents.perception.refine import (
    RefineConfig,
    _edge_nearest,
    _local_maxima,
    _radial_steps,
    _ray_points,
    _robust_fit,
    _sample,
    _subsample,
    coarse_score,
)
from agents.perception.refine import refine_circles as _refine_circles  # (this module's refine_circles wraps it)

__all__ = ["RimRefineConfig", "coarse_fit", "radial_edges", "refine_circles", "rim_votes"]


@dataclass(frozen=True)
class RimRefineConfig(RefineConfig):
    """Parameters of the rim search and fit: those of :class:`~agents.perception.refine.RefineConfig`
    (the default detector's rim fit; ``band`` and ``coarse_samples`` unused here), and

    Attributes
    ----------
    min_rim_step : float
        Second pass: smallest median step (summed over the colour channels, per pixel) of the
        rays supporting a circle.
    ellipse_margin : float
        Second pass: the ellipse replaces the circle only when it explains this share of the rays
        more (a shaded limb or a partly hidden rim fits an ellipse a little better by chance).
    vote_band : (float, float)
        First pass (:func:`rim_votes`): rim radii searched, as multiples of the proposal's radius
        (a proposal on the tag inside a node is 0.3-0.6 of the node's radius).
    search_candidates, search_hypotheses : int
        First pass (:func:`rim_search`): candidate edges per ray, and three-point circles tried.
    search_below : float
        First pass: proposals whose voted rim scores below this are also searched.
    vote_samples : int
        Samples of the log-spaced radius grid of the vote.
    vote_floor : float
        An edge votes when its step is at least this fraction of its ray's strongest.
    vote_width : int
        Each vote spreads over +- this many grid samples (the relative tolerance of the rim radius
        across rays, for a rough centre).
    vote_keep : float
        The rim is the outermost vote peak with at least this fraction of the best peak's votes.
    """

    ellipse_margin: float = 0.05
    min_rim_step: float = 12.0
    vote_band: tuple[float, float] = (0.5, 3.0)
    search_candidates: int = 4
    search_below: float = 0.7
    search_hypotheses: int = 32
    vote_samples: int = 40
    vote_floor: float = 0.05
    vote_width: int = 2
    vote_keep: float = 0.6


def rim_votes(image: np.ndarray, centres: np.ndarray, cfg: RimRefineConfig, band: tuple[float, float] | None = None,
              width: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The sphere's rim around each rough centre, by a vote of all rays on its radius.

    A node's rim is the one edge that every ray from (near) its centre crosses at about the same
    distance; its tag's edges, the floor's texture and neighbouring nodes give edges at distances
    that vary from ray to ray. So along each ray the edges (local maxima of the radial step, at
    least ``min_step`` and ``vote_floor`` of the ray's strongest) vote for their distance, weighted by
    their share of the ray's strongest step and spread over +-``vote_width`` samples of a
    log-spaced radius grid (a fixed relative tolerance, for a centre a little off); the rim is the
    outermost peak of the votes with at least ``vote_keep`` of the best peak's votes (the rim
    encloses the tag; an outer edge with as many votes as the tag's is the rim). On each ray the edge
    nearest that radius is then the rim point. This finds the rim of a large node whose colour is
    close to the floor's (weak rim steps, strong tag edges) where taking each ray's outermost strong
    edge found the tag.

    Parameters
    ----------
    centres : ndarray, shape (N, 3)
        Rough circles (u, v, r): the radius only sets the searched range ``cfg.vote_band`` times r.

    Returns
    -------
    points : ndarray, shape (N, coarse_rays, 2)
    strength : ndarray, shape (N, coarse_rays)
        0 where a ray has no edge within ``vote_width`` samples of the chosen radius.
    radius : ndarray, shape (N,)
        The chosen rim radius (px).
    """
    lo, hi = band or cfg.vote_band
    width = width or cfg.vote_width
    samples = cfg.vote_samples if band is None else max(int(round(cfg.vote_samples * np.log(hi / lo) / np.log(cfg.vote_band[1] / cfg.vote_band[0]))), 8)
    grid = np.exp(np.linspace(np.log(lo), np.log(hi), samples))
    rad = centres[:, 2, None] * grid[None, :]
    deriv, inside, cos, sin = _radial_steps(image, centres, rad, cfg.coarse_rays)
    strongest = deriv.max(axis=2, keepdims=True)
    cand = _local_maxima(deriv) & (deriv >= np.maximum(cfg.vote_floor * strongest, cfg.min_step)) & inside[..., None]
    weight = np.where(cand, deriv / np.maximum(strongest, 1e-6), 0.0).astype(np.float32)
    spread = weight.copy()
    for s in range(1, width + 1):  # a ray votes once per radius: the max over the window
        np.maximum(spread[..., s:], weight[..., :-s], out=spread[..., s:])
        np.maximum(spread[..., :-s], weight[..., s:], out=spread[..., :-s])
    votes = spread.sum(axis=1)  # (N, S - 1)
    peaks = _local_maxima(votes) & (votes >= cfg.vote_keep * votes.max(axis=1, keepdims=True)) & (votes > 0)
    last = votes.shape[1] - 1
    kstar = last - np.argmax(peaks[:, ::-1], axis=1)  # the outermost qualifying peak
    # on each ray, the edge nearest the chosen radius (within the vote window)
    k, gap = _edge_nearest(deriv, cand, kstar)
    near = gap <= width
    peak, off = _subsample(deriv, k)
    pos = np.clip(k[..., 0] + 0.5 + off[..., 0], 0, last + 1)  # fractional sample index of the edge
    dist = np.exp(np.log(lo) + pos * (np.log(hi) - np.log(lo)) / (samples - 1)) * centres[:, 2, None]
    pts = _ray_points(centres, cos, sin, dist[..., None])[:, :, 0]
    strength = np.where(near, peak[..., 0], 0.0)
    radius = centres[:, 2] * np.exp(np.log(lo) + (kstar + 0.5) * (np.log(hi) - np.log(lo)) / (samples - 1))
    return pts, strength, radius


def radial_edges(image: np.ndarray, points: np.ndarray, circles: np.ndarray, max_turn: float = 0.5) -> np.ndarray:
    """Whether the image gradient at each rim point points along its ray (across the circle).

    A sphere's rim is perpendicular to every ray from its centre, so the intensity gradient there is
    radial; the edges a textured floor, a straight strut or a tag's square offer at the right
    distance mostly are not. The gradient is taken by central differences (1 px) of the lightly
    smoothed image at the points themselves, per channel; a point is radial when the channels'
    summed absolute tangential component is at most ``max_turn`` times the radial one (about 27 deg).

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, C), float32
    points : ndarray, shape (N, R, 2)
    circles : ndarray, shape (N, 3)

    Returns
    -------
    ndarray of bool, shape (N, R)
    """
    n, r = points.shape[:2]
    px = points[..., 0].astype(np.float32).reshape(n * r, 1)
    py = points[..., 1].astype(np.float32).reshape(n * r, 1)
    # the four neighbours of every point in one remap: columns (x+1, x-1, y+1, y-1)
    mx = np.concatenate([px + 1, px - 1, px, px], axis=1)
    my = np.concatenate([py, py, py + 1, py - 1], axis=1)
    img = image if image.dtype == np.float32 else image.astype(np.float32)
    vals = _sample(img, mx, my)
    vals = vals.reshape(n * r, 4, -1)
    gx, gy = vals[:, 0] - vals[:, 1], vals[:, 2] - vals[:, 3]  # (P, C)
    d = points - circles[:, None, :2]
    norm = np.maximum(np.hypot(d[..., 0], d[..., 1]), 1e-9)
    cos, sin = (d[..., 0] / norm).reshape(-1, 1), (d[..., 1] / norm).reshape(-1, 1)
    radial = np.abs(gx * cos + gy * sin).sum(axis=1)
    tangential = np.abs(gy * cos - gx * sin).sum(axis=1)
    return (tangential <= max_turn * radial).reshape(n, r)


def _circles_through(p1: np.ndarray, p2: np.ndarray, p3: np.ndarray) -> np.ndarray:
    """Circles (..., 3) through three points (..., 2) each; NaN where they are collinear."""
    ax, ay = p1[..., 0], p1[..., 1]
    bx, by = p2[..., 0] - ax, p2[..., 1] - ay
    cx, cy = p3[..., 0] - ax, p3[..., 1] - ay
    d = 2.0 * (bx * cy - by * cx)
    safe = np.where(np.abs(d) > 1e-9, d, np.nan)
    b2, c2 = bx * bx + by * by, cx * cx + cy * cy
    ux, uy = (cy * b2 - by * c2) / safe, (bx * c2 - cx * b2) / safe
    return np.stack([ax + ux, ay + uy, np.hypot(ux, uy)], axis=-1)


def _triples(rays: int, candidates: int, count: int) -> tuple[np.ndarray, np.ndarray]:
    """A fixed set of ``count`` ray triples about 120 deg apart, and which candidate edge each uses."""
    gen = np.random.default_rng(12345)  # a fixed design, the same for every frame
    a = gen.integers(0, rays, count)
    third = rays / 3.0
    jitter = gen.integers(-int(third // 4), int(third // 4) + 1, (count, 2))
    idx = np.stack([a, (a + np.round(third).astype(int) + jitter[:, 0]) % rays,
                    (a + np.round(2 * third).astype(int) + jitter[:, 1]) % rays], axis=1)
    pick = np.zeros((count, 3), dtype=int)
    pick[candidates:] = gen.integers(0, candidates, (count - candidates, 3))
    pick[:candidates] = np.arange(candidates)[:, None]  # all-outermost, all-second, ... first
    return idx, pick


def rim_search(image: np.ndarray, rough: np.ndarray, cfg: RimRefineConfig) -> tuple[np.ndarray, np.ndarray]:
    """The circle best supported by the rays' edges around each rough circle, wherever its centre.

    Along every ray from the rough centre the outermost edge with at least ``outer_frac`` of the
    ray's strongest step and the ``cfg.search_candidates - 1`` strongest edges between
    ``vote_band[0]`` and ``vote_band[1]`` times the rough radius are candidates. Circles through
    three candidates on rays about 120 deg apart (a fixed design of ``cfg.search_hypotheses``
    triples) are scored by the rays that have a candidate within 6 % (+1 px) of them, each weighted
    by its step's share of its ray's strongest; the best circle wins. Unlike a vote on the distance
    from the rough centre this finds the rim from a centre far off it: a proposal on a node's tag,
    which may sit near the node's limb.

    Returns
    -------
    circles : ndarray, shape (N, 3)
    support : ndarray, shape (N,)
        Weighted share of rays supporting each circle (0-1).
    """
    n = len(rough)
    c = cfg.search_candidates
    lo, hi = cfg.vote_band
    rad = rough[:, 2, None] * np.exp(np.linspace(np.log(lo), np.log(hi), cfg.vote_samples))[None, :]
    deriv, inside, cos, sin = _radial_steps(image, rough, rad, cfg.coarse_rays)
    edges = np.where(_local_maxima(deriv) & (deriv >= cfg.min_step) & inside[..., None], deriv, 0.0)
    # the ray's strongest edges, and its outermost with a tenth of the strongest's step (a node's
    # rim is its outermost edge, while its tag's edges are often the strongest)
    strongest = np.argsort(-edges, axis=2, kind="stable")[..., :c - 1]
    qualify = edges >= cfg.outer_frac * edges.max(axis=2, keepdims=True)
    last = edges.shape[2] - 1
    outermost = last - np.argmax(qualify[..., ::-1], axis=2)
    k = np.concatenate([outermost[..., None], strongest], axis=2)
    strength, off = _subsample(edges, k)
    pos = k + 0.5 + off  # fractional sample index: between samples k and k + 1
    dist = np.exp(np.log(lo) + pos * (np.log(hi) - np.log(lo)) / (cfg.vote_samples - 1)) * rough[:, 2, None, None]
    pts = _ray_points(rough, cos, sin, dist)  # (N, R, C, 2)
    weight = strength / np.maximum(strength.max(axis=2, keepdims=True), 1e-6)
    idx, pick = _triples(cfg.coarse_rays, c, cfg.search_hypotheses)
    tri = pts[:, idx, pick]  # (N, T, 3, 2)
    ok_tri = (strength[:, idx, pick] > 0).all(axis=2)
    hyp = _circles_through(tri[:, :, 0], tri[:, :, 1], tri[:, :, 2])  # (N, T, 3)
    r0 = rough[:, 2, None]
    shift = np.hypot(hyp[..., 0] - rough[:, 0, None], hyp[..., 1] - rough[:, 1, None])
    ok_tri &= np.isfinite(hyp).all(axis=2) & (hyp[..., 2] >= cfg.vote_band[0] * r0) & (hyp[..., 2] <= cfg.vote_band[1] * r0)
    ok_tri &= shift <= cfg.max_shift * hyp[..., 2]
    d = np.hypot(pts[:, None, :, :, 0] - hyp[:, :, None, None, 0], pts[:, None, :, :, 1] - hyp[:, :, None, None, 1])
    near = np.abs(d - hyp[:, :, None, None, 2]) <= (0.06 * hyp[:, :, None, None, 2] + 1.0)
    support = np.where(near, weight[:, None], 0.0).max(axis=3).sum(axis=2) / cfg.coarse_rays  # (N, T)
    support = np.where(ok_tri, support, -1.0)
    best = np.argmax(support, axis=1)
    circles = hyp[np.arange(n), best]
    found = support[np.arange(n), best] > 0
    return np.where(found[:, None], circles, rough), np.where(found, support[np.arange(n), best], 0.0)


def coarse_fit(image: np.ndarray, rough: np.ndarray, cfg: RimRefineConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """First pass on every proposal: the rim voted from the proposal's centre (:func:`rim_votes`;
    right when that centre is, even on a weak rim), and where that finds no good rim (score below
    ``cfg.search_below``) also the best-supported three-edge circle (:func:`rim_search`; right from
    a centre far off, such as a tag near the node's limb). Each start is re-voted from its own
    centre over a narrow range and fitted robustly with shrinking gates.

    Returns
    -------
    circles : ndarray, shape (M, 3)
        One circle per proposal, then one per searched proposal (N <= M <= 2N).
    scores : ndarray, shape (M,)
        Share of the coarse rays whose rim point lies within the tolerance and whose gradient is
        radial (:func:`radial_edges`).
    ok : ndarray of bool, shape (M,)
    """
    rough = np.asarray(rough, dtype=float).reshape(-1, 3)
    if len(rough) == 0:
        return rough.copy(), np.zeros(0), np.zeros(0, dtype=bool)
    pts, strength, r0 = rim_votes(image, rough, cfg)
    voted, vok = _robust_fit(pts, strength, np.column_stack([rough[:, :2], r0]), [0.25 * r0, 0.12 * r0])
    circles, scores, ok = _settle(image, np.where(vok[:, None], voted, rough), rough, cfg)
    weak = scores < cfg.search_below
    if not weak.any():
        return circles, scores, ok
    searched, _ = rim_search(image, rough[weak], cfg)
    more, more_scores, more_ok = _settle(image, searched, rough[weak], cfg)
    return (np.concatenate([circles, more]), np.concatenate([scores, more_scores]), np.concatenate([ok, more_ok]))


def _settle(image: np.ndarray, found: np.ndarray, rough: np.ndarray, cfg: RimRefineConfig):
    """Re-vote the rim of circles ``found`` (N, 3) from their own centres, fit robustly, score."""
    pts, strength, r0 = rim_votes(image, found, cfg, band=(0.75, 1.35))
    start = np.column_stack([found[:, :2], r0])
    return coarse_score(pts, strength, start, rough, r0, [0.12 * r0, 0.06 * r0], cfg,
                        edges=lambda p, c: radial_edges(image, p, c))


def refine_circles(image: np.ndarray, rough: np.ndarray, cfg: RimRefineConfig, *, nearest: bool = True
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The default detector's fine fit (:func:`agents.perception.refine.refine_circles`: a narrow band
    around each rough (N, 3) circle, gated fits, the ellipse stage) with the rim detectors' rules: on
    each ray the edge nearest the rough circle (``nearest``, default) or else the outermost strong
    one, an ellipse kept only by ``cfg.ellipse_margin`` more rays, inliers whose gradient points along
    the ray (:func:`radial_edges`), and a median edge step of at least ``cfg.min_rim_step``.
    Returns (circles (N, 3), scores (N,), ok (N,)) as that function."""
    return _refine_circles(image, rough, cfg, nearest=nearest, ellipse_margin=cfg.ellipse_margin,
                           edges=lambda p, c: radial_edges(image, p, c), min_step=cfg.min_rim_step)
