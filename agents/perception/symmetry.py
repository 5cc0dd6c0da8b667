"""Circle candidates from colour edges voting for centres along their gradient (radial symmetry).

A sphere's rim is an edge all around whose gradient points along the ray from the centre, whatever
the sign of the step (a shaded sphere is darker than the floor on one side and brighter on the
other) and whichever colour channel carries it (a sphere as bright as the floor differs in hue).
So each edge pixel of a colour Canny map (the channel with the largest gradient at each pixel) votes
at distance ``n`` on both sides along its gradient, for a ladder of radii ``n``; where the rim of a
circle of radius about ``n`` lies, the votes pile up at its centre. The votes of radius ``n`` in a
window of ``± window * n`` around a pixel, divided by the circle's perimeter ``2 pi n``, are the share
of that circle's rim that is an edge facing its centre: the candidate's support, comparable across
radii. This is the fast radial symmetry transform of Loy and Zelinsky ("Fast radial symmetry for
detecting points of interest", IEEE TPAMI 2003) with sign-free votes counted on thin edges.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from agents.perception.circle_fit import circle_residuals
from agents.perception.heap import keep_freed_memory
from agents.perception.hough import HoughCircleDetector, HoughConfig, _blur_float, _dedupe, suppress, to_grey
from agents.perception.rim import _inner_contrast
from agents.perception.refine import _nearest, _robust_fit, rim_points
from agents.perception.rim_refine import RimRefineConfig, radial_edges, refine_circles
from agents.perception.types import Circle

__all__ = ["SymmetryCircleDetector", "SymmetryConfig", "radius_ladder", "symmetry_candidates", "verify_circles"]


def radius_ladder(r_lo: float, r_hi: float, window: float) -> np.ndarray:
    """Radii from ``r_lo`` to at least ``r_hi`` spaced so that windows of ``± window * n`` just meet."""
    ratio = (1.0 + window) / (1.0 - window)
    count = max(int(np.ceil(np.log(r_hi / r_lo) / np.log(ratio))) + 1, 1)
    return r_lo * ratio ** np.arange(count)


def _edge_normals(image: np.ndarray, canny: tuple[float, float]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Thin edges of a uint8 image (grey or BGR) and their unit gradients: x, y (E,) int, cos, sin (E,) float32.

    On a colour image each pixel's gradient is that of its channel with the largest gradient (as
    ``cv2.Canny`` takes it).
    """
    dx = cv2.Sobel(image, cv2.CV_16S, 1, 0)
    dy = cv2.Sobel(image, cv2.CV_16S, 0, 1)
    edges = cv2.Canny(dx, dy, canny[0], canny[1], L2gradient=True)
    ys, xs = np.nonzero(edges)
    gx, gy = dx[ys, xs].astype(np.float32), dy[ys, xs].astype(np.float32)
    if gx.ndim == 2:  # (E, C): the strongest channel
        c = np.argmax(gx * gx + gy * gy, axis=1)[:, None]
        gx, gy = np.take_along_axis(gx, c, axis=1)[:, 0], np.take_along_axis(gy, c, axis=1)[:, 0]
    mag = np.maximum(np.hypot(gx, gy), 1e-6)
    return xs, ys, gx / mag, gy / mag


def symmetry_candidates(
    image: np.ndarray,
    radii: np.ndarray,
    *,
    canny: tuple[float, float] = (20.0, 40.0),
    window: float = 0.1,
    min_support: float = 0.25,
    max_candidates: int = 60,
) -> np.ndarray:
    """Circle candidates of a uint8 image (grey or BGR) at the radii ``radii`` (px of this image).

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, 3), uint8
        Usually a downscaled frame (candidates are rough; the rim is refined at full resolution).
    radii : ndarray, shape (K,)
        Increasing radii voted for (e.g. :func:`radius_ladder`).
    canny : (float, float)
        Hysteresis thresholds of the edge map (on the Sobel gradient of the strongest channel).
    window : float
        Votes within ``± window * n`` (at least 1 px) of a pixel count towards it.
    min_support : float
        Smallest share of a candidate's perimeter voting for it.
    max_candidates : int
        At most this many candidates, best supported first.

    Returns
    -------
    ndarray, shape (N, 4)
        (u, v, r, support) in this image's pixels, best supported first; candidates are local maxima
        of the support over position and radius (the 3 x 3 x 3 neighbourhood).
    """
    h, w = image.shape[:2]
    xs, ys, cx, cy = _edge_normals(image, canny)
    if len(xs) == 0 or len(radii) == 0:
        return np.zeros((0, 4))
    support = np.empty((len(radii), h, w), np.float32)
    # both signs of each edge's normal at once; votes off the image land on a one-pixel frame
    # around it (the accumulator is padded), which is then cut away
    x2 = np.concatenate([xs, xs]).astype(np.float32)
    y2 = np.concatenate([ys, ys]).astype(np.float32)
    c2, s2 = np.concatenate([cx, -cx]), np.concatenate([cy, -cy])
    for k, n in enumerate(radii):
        px = np.clip(np.rint(x2 + np.float32(n) * c2), -1, w).astype(np.int32) + 1
        py = np.clip(np.rint(y2 + np.float32(n) * s2), -1, h).astype(np.int32) + 1
        votes = np.bincount(py * (w + 2) + px, minlength=(h + 2) * (w + 2)).astype(np.float32)
        votes = votes.reshape(h + 2, w + 2)[1:-1, 1:-1]
        half = max(int(round(window * n)), 1)
        side = 2 * half + 1
        cv2.boxFilter(votes, -1, (side, side), dst=support[k], normalize=False, borderType=cv2.BORDER_CONSTANT)
        # less the votes a window receives by chance where edges are dense (a textured floor):
        # the mean over a window of the circle's size
        # less the votes a window receives by chance where edges are dense (a textured floor):
        # the mean over a window of the circle's size
        wide = 2 * int(round(n)) + 1
        support[k] -= cv2.boxFilter(votes, -1, (wide, wide), borderType=cv2.BORDER_REFLECT) * np.float32(side * side)
        support[k] *= np.float32(1.0 / (2.0 * np.pi * n))
    # peaks of the best support over radii (3 x 3 local maxima), then at each peak every radius
    # whose support is a local maximum along the radius ladder (a rim and the tag inside it)
    best = support.max(axis=0)
    peak = (best >= cv2.dilate(best, np.ones((3, 3), np.uint8))) & (best >= min_support)
    vs, us = np.nonzero(peak)
    prof = support[:, vs, us]  # (K, P)
    up = np.ones(prof.shape, dtype=bool)
    up[1:] &= prof[1:] >= prof[:-1]
    up[:-1] &= prof[:-1] > prof[1:]
    ks, ps = np.nonzero(up & (prof >= min_support))
    sup = prof[ks, ps]
    order = np.argsort(-sup, kind="stable")[:max_candidates]
    return np.column_stack([us[ps[order]], vs[ps[order]], np.asarray(radii)[ks[order]], sup[order]]).astype(float)


@dataclass(frozen=True)
class SymmetryConfig:
    """Parameters of :class:`SymmetryCircleDetector`.

    Attributes
    ----------
    levels : tuple of (scale, r_lo, r_hi)
        Candidates of full-resolution radius in [r_lo, r_hi] are voted for on the frame resized by
        ``scale`` (the vote's cost grows with the image and the radius ladder).
    canny : (float, float)
        Hysteresis thresholds of the colour edge map (Sobel units: 4 per grey level of a step).
    window : float
        Relative radius tolerance of a vote (:func:`symmetry_candidates`).
    min_support : float
        Smallest vote support of a candidate.
    max_candidates : int
        At most this many candidates per level, best supported first.
    hough_proposals : int
        The strongest proposals per level of the default detector's grey Hough transform
        (:meth:`agents.perception.hough.HoughCircleDetector.proposals`) join the candidates (0: none).
    verify_band : (float, float)
        The verification searches each candidate's rays between these multiples of its radius.
    verify_edges : int
        Edges per ray kept by the verification; the one nearest the candidate's circle is used.
    verify_min_score, verify_min_score_px : float
        Candidates whose verified rim support (share of the coarse rays) is below
        ``verify_min_score + verify_min_score_px / r`` are dropped (a small circle needs more
        support: its rim crosses few pixels, and texture edges line up on it by chance more often).
    dedupe : float
        Verified circles within this share of a better one's radius in centre and radius are
        dropped before the fine pass (a wide merge lost rims to a nearby circle on an isophote).
    min_radius, max_radius : int
        Radius range in pixels of the returned circles.
    refine_blur : float
        Gaussian sigma (px) of the full-resolution image the rim is refined on.
    min_score : float
        Circles whose refined rim support (share of the rays) is below this are dropped.
    max_circles : int
        At most this many circles are returned (best score first).
    refine : RefineConfig
        Rim search and fit parameters of the full-resolution refinement.
    """

    levels: tuple[tuple[float, float, float], ...] = ((0.5, 7.0, 24.0), (0.25, 20.0, 100.0), (0.125, 90.0, 170.0))
    canny: tuple[float, float] = (30.0, 60.0)
    window: float = 0.1
    min_support: float = 0.2
    max_candidates: int = 20
    hough_proposals: int = 8
    verify_band: tuple[float, float] = (0.8, 1.25)
    verify_edges: int = 4
    verify_min_score: float = 0.3
    verify_min_score_px: float = 2.0
    dedupe: float = 0.06
    min_radius: int = 8
    max_radius: int = 160
    refine_blur: float = 1.0
    min_score: float = 0.5
    min_score_px: float = 2.5
    outer_tie: float = 0.9
    retry_score: float = 0.3
    weak_score: float = 0.35
    weak_contrast: float = 130.0
    retries: int = 1
    max_circles: int = 64
    refine: RimRefineConfig = field(default_factory=RimRefineConfig)


class SymmetryCircleDetector:
    """Radial-symmetry candidates + rim verification and refinement; a :class:`~agents.perception.types.CircleDetector`."""

    def __init__(self, config: SymmetryConfig | None = None):
        self.config = config or SymmetryConfig()
        self._fine: np.ndarray | None = None  # the blurred frame's buffer, reused (see HoughCircleDetector)
        cfg = self.config
        self._hough = HoughCircleDetector(HoughConfig(min_radius=cfg.min_radius, max_radius=cfg.max_radius,
                                                      max_proposals=cfg.hough_proposals))
        keep_freed_memory()

    def candidates(self, image: np.ndarray) -> np.ndarray:
        """Rough circles (N, 4) as (u, v, r, support) in full-image pixels over all levels."""
        cfg = self.config
        out = []
        for s, r_lo, r_hi in cfg.levels:
            lo, hi = max(r_lo, 0.9 * cfg.min_radius), min(r_hi, 1.1 * cfg.max_radius)
            if hi <= lo:
                continue
            small = image if s == 1.0 else cv2.resize(image, None, fx=s, fy=s, interpolation=cv2.INTER_AREA)
            found = symmetry_candidates(small, radius_ladder(lo * s, hi * s, cfg.window), canny=cfg.canny,
                                        window=cfg.window, min_support=cfg.min_support,
                                        max_candidates=cfg.max_candidates)
            found[:, :2] = (found[:, :2] + 0.5) / s - 0.5
            found[:, 2] /= s
            out.append(found)
        if cfg.hough_proposals:
            # the grey Hough transform's strongest circles too: it finds rims broken up by tags
            # printed all over a node (whose edges scatter the symmetry votes), at little cost
            rough = self._hough.proposals(to_grey(image))
            out.append(np.column_stack([rough, np.zeros(len(rough))]))
        return np.concatenate(out) if out else np.zeros((0, 4))

    def detect(self, image: np.ndarray) -> list[Circle]:
        """Return the verified, refined, suppressed circles of ``image``, best score first."""
        cfg = self.config
        image = np.asarray(image)
        if image.ndim == 3 and image.shape[2] == 4:
            image = cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
        elif image.ndim != 2 and not (image.ndim == 3 and image.shape[2] == 3):
            raise ValueError(f"expected a (H, W), (H, W, 3) or (H, W, 4) image, got shape {image.shape}")
        if image.size == 0:
            return []
        rough = self.candidates(image)
        if len(rough) == 0:
            return []
        if self._fine is None or self._fine.shape != image.shape:
            self._fine = np.empty(image.shape, np.float32)
        fine_img = _blur_float(image, cfg.refine_blur, out=self._fine)
        circles, scores, ok = verify_circles(fine_img, rough[:, :3], cfg.verify_band, cfg.verify_edges, cfg.refine)
        ok &= (scores >= cfg.verify_min_score + cfg.verify_min_score_px / np.maximum(circles[:, 2], 1.0)) & (circles[:, 2] >= 0.8 * cfg.min_radius) & (circles[:, 2] <= 1.2 * cfg.max_radius)
        # repeats of one circle are merged (best first); nested circles all go on to the fine pass
        cand = np.column_stack([circles[ok], scores[ok]])
        coarse = _dedupe(cand[np.argsort(-cand[:, 3], kind="stable")][:, :3], cfg.dedupe)
        if len(coarse) == 0:
            return []
        circles, scores, ok = _refine_outward(fine_img, coarse, cfg.refine, cfg.min_score, cfg.outer_tie, cfg.retry_score)
        scores = _on_image_scores(circles, scores, image.shape, cfg.refine)
        # a circle a little off a rim that a tag or a neighbour crowds converges over further passes
        # (the first fits, with tight gates, hold to the rays already on the rim)
        need = cfg.min_score + cfg.min_score_px / np.maximum(circles[:, 2], 1.0)
        retry = ok & (scores < need) & (scores >= cfg.retry_score)
        for _ in range(cfg.retries if retry.any() else 0):
            again, again_scores, again_ok = refine_circles(fine_img, circles[retry], cfg.refine)
            again_scores = _on_image_scores(again, again_scores, image.shape, cfg.refine)
            better = again_ok & (again_scores > scores[retry])
            idx = np.flatnonzero(retry)[better]
            circles[idx], scores[idx] = again[better], again_scores[better]
        need = cfg.min_score + cfg.min_score_px / np.maximum(circles[:, 2], 1.0)
        # a weakly supported circle (a node whose rim is half hidden by its struts and neighbours)
        # is kept with a print inside it: floor texture gives round rims of that support, but no tag
        weak = ok & (scores < need) & (scores >= cfg.weak_score)
        if weak.any():
            weak[weak] = _inner_contrast(fine_img, circles[weak]) >= cfg.weak_contrast
        ok &= (scores >= need) | weak
        found = [Circle(*map(float, c), float(min(s, 1.0))) for c, s in zip(circles[ok], scores[ok])]
        return suppress(found)[: cfg.max_circles]


def verify_circles(image: np.ndarray, rough: np.ndarray, band: tuple[float, float], edges: int, cfg: RimRefineConfig
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """First pass on every candidate: on each of ``cfg.coarse_rays`` rays the ``edges`` outermost
    edges between ``band`` times the radius; a robust fit (shrinking gates) to the edge nearest the
    candidate's circle on each ray, and one to the outermost edges (the candidate's radius may be
    that of an isophote inside a shaded limb).

    Returns
    -------
    circles : ndarray, shape (2N, 3)
        The fits to the nearest edges, then those to the outermost.
    scores : ndarray, shape (2N,)
        Share of the rays whose edge lies within the tolerance of the fitted circle and has a
        radial gradient (:func:`agents.perception.rim_refine.radial_edges`).
    ok : ndarray of bool, shape (2N,)
    """
    rough = np.asarray(rough, dtype=float).reshape(-1, 3)
    if len(rough) == 0:
        return rough.copy(), np.zeros(0), np.zeros(0, dtype=bool)
    every, strength = rim_points(image, rough, band, cfg, rays=cfg.coarse_rays, samples=cfg.coarse_samples,
                                 candidates=edges)
    out = []
    for pts, st in (_nearest(every, strength, rough), (every[:, :, 0], strength[:, :, 0])):
        circles, _, ok = _fit_and_score(image, pts, st, rough, cfg)
        # again with the edges nearest the fit (on a partly hidden rim the outermost edges of the
        # hidden side belong to what hides it)
        start = np.where(ok[:, None], circles, rough)
        out.append(_fit_and_score(image, *_nearest(every, strength, start), start, cfg, rough))
    return tuple(np.concatenate(parts) for parts in zip(*out))


def _fit_and_score(image, pts, strength, rough, cfg: RimRefineConfig, origin=None):
    """A robust circle fit (shrinking gates) to one rim point per ray from ``rough``, and its score
    (a centre more than ``cfg.max_shift`` radii from ``origin``, default ``rough``, fails)."""
    origin = rough if origin is None else origin
    r0 = rough[:, 2]
    tol = cfg.tol + cfg.tol_rel * r0 + 0.02 * r0
    circles, ok = _robust_fit(pts, strength, rough, [0.15 * r0, 0.08 * r0, tol])
    inl = (strength > 0) & (np.abs(circle_residuals(pts, circles)) < tol[:, None])
    inl &= radial_edges(image, pts, circles)
    shift = np.hypot(circles[:, 0] - origin[:, 0], circles[:, 1] - origin[:, 1])
    ok &= (inl.sum(axis=1) >= 4) & (shift <= cfg.max_shift * origin[:, 2]) & np.all(np.isfinite(circles), axis=1)
    ok &= circles[:, 2] > 0
    return circles, np.where(ok, inl.sum(axis=1) / cfg.coarse_rays, 0.0), ok


def _on_image_scores(circles: np.ndarray, scores: np.ndarray, shape: tuple, cfg: RimRefineConfig) -> np.ndarray:
    """Scores (shares of all rays) as shares of the rays whose rim band lies in the image, for
    circles with at least half their rays there (a sphere cut by the image border); at most 1."""
    h, w = shape[:2]
    ang = np.linspace(0.0, 2.0 * np.pi, cfg.rays, endpoint=False)
    reach = cfg.fine_band[1] * circles[:, 2, None]
    x = circles[:, 0, None] + reach * np.cos(ang)[None, :]
    y = circles[:, 1, None] + reach * np.sin(ang)[None, :]
    inside = ((x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1)).mean(axis=1)
    return np.minimum(np.where(inside >= 0.5, scores / np.maximum(inside, 0.5), scores), 1.0)


def _refine_outward(image: np.ndarray, coarse: np.ndarray, cfg: RimRefineConfig, min_score: float, outer_tie: float,
                    floor: float):
    """Each circle refined with the rim as the edge nearest it on each ray (a neighbour or floor texture
    just outside cannot take it) and as the outermost strong edge (unbiased where the shaded limb
    offers weaker edges nearer to a circle a little too small), both on the coarse rays without the
    ellipse fit; then the better one, if it scores at least ``floor``, on all rays. Of nearly as well
    supported circles the larger wins. Returns (circles, scores, ok) as
    :func:`agents.perception.rim_refine.refine_circles`."""
    circles, scores, ok = coarse[:, :3].copy(), np.zeros(len(coarse)), np.zeros(len(coarse), dtype=bool)
    quick = replace(cfg, max_axis_ratio=1.0, rays=cfg.coarse_rays)
    for nearest in (True, False):
        again, again_scores, again_ok = refine_circles(image, coarse[:, :3], quick, nearest=nearest)
        _keep_better(circles, scores, again, again_scores, again_ok, min_score, outer_tie)
        ok |= again_ok
    todo = np.flatnonzero(ok & (scores >= floor))
    if len(todo):
        sub_c, sub_s = circles[todo], scores[todo]
        again, again_scores, again_ok = refine_circles(image, sub_c, cfg)
        _keep_better(sub_c, sub_s, again, again_scores, again_ok, min_score, outer_tie)
        circles[todo], scores[todo] = sub_c, sub_s
    return circles, scores, ok


def _keep_better(circles, scores, again, again_scores, again_ok, min_score: float, outer_tie: float) -> None:
    """Replace (in place) circles by their refinements ``again`` where those are better: a larger one
    with at least ``outer_tie`` of the score (and the threshold, or a higher score), a smaller one
    with a score higher by more than a factor ``1 / outer_tie``."""
    wider = again[:, 2] > circles[:, 2]
    better = again_ok & np.where(wider, (again_scores >= outer_tie * scores)
                                 & ((again_scores >= min_score) | (again_scores > scores)),
                                 again_scores * outer_tie > scores)
    circles[better], scores[better] = again[better], again_scores[better]
