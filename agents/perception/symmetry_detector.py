"""The symmetry circle detector (``detector="symmetry"``): symmetry candidates, rim verification, refinement.

:class:`SymmetryCircleDetector` proposes circles from colour edges voting for their centres
(:func:`agents.perception.symmetry.symmetry_candidates`, on the frame at half, quarter and eighth
resolution) plus the default detector's strongest grey Hough circles, so a sphere whose brightness is
close to the floor's, or whose rim its tag breaks up, still gets a candidate. Each candidate is
verified on coarse rays at full resolution (:func:`verify_circles`: the edges nearest it and the
outermost ones, only edges with a radial gradient count), then refined outward
(:func:`agents.perception.rim_refine.refine_circles`, nearest and outermost edges, the larger of
nearly as well supported circles wins) so the circle is the sphere's rim, not its tag; a partly
hidden sphere's circle comes from its visible rim (the robust fit drops the hidden rays). Circles
are kept above a score threshold that rises for small radii, and nested circles are suppressed
largest first (:func:`agents.perception.hough.suppress`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from agents.perception.circle_fit import circle_residuals
from agents.perception.heap import keep_freed_memory
from agents.perception.hough import HoughCircleDetector, HoughConfig, _blur_float, _dedupe, suppress, to_grey
from agents.perception.refine import _nearest, _robust_fit, rim_points
from agents.perception.rim import _inner_contrast, keep_better
from agents.perception.rim_refine import RimRefineConfig, radial_edges, refine_circles
from agents.perception.symmetry import radius_ladder, symmetry_candidates
from agents.perception.types import Circle

__all__ = ["SymmetryCircleDetector", "SymmetryConfig", "verify_circles"]


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
    min_score, min_score_px : float
        Circles whose refined rim support (share of the rays inside the image) is below
        ``min_score + min_score_px / r`` are dropped, unless they are weak circles with a print
        inside (``weak_score``).
    outer_tie : float
        Of the refinements of one circle, a larger one wins with at least this share of a smaller
        one's score (inside a shaded limb the isophotes are circles with radial gradients too).
    weak_score, weak_contrast : float
        Circles short of the threshold that score at least ``weak_score`` are kept when the image
        inside 0.7 of their radius spreads by at least ``weak_contrast`` grey levels (summed over
        the channels): a tagged node whose rim its struts and neighbours hide in part.
    retry_score, retries, retry_margin : float, int, float
        Only circles scoring at least ``retry_score`` on the coarse rays are refined on all rays;
        those that then fall short of the threshold by at most ``retry_margin`` (and score at least
        ``retry_score``) are refined ``retries`` more times from their own result (circles further
        below gained nothing from it on the tuning scenes, and were a third of the refinement's cost).
    strong : float
        Suppression (:func:`agents.perception.hough.suppress`): of nested circles scoring at least
        this, the largest is kept (a rim around its tag); weaker ones are kept best first.
    repeat : float
        Accepted circles whose centres and radii lie within this share of the larger radius are
        repeats of one rim: the best scored is kept, or a larger one scoring at least ``outer_tie``
        of it (before suppression, whose largest-first rule would keep a repeat a little too large).
    max_circles : int
        At most this many circles are returned (best score first).
    refine : RimRefineConfig
        Rim search and fit parameters of the verification and the full-resolution refinement.
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
    weak_contrast: float = 80.0
    retries: int = 1
    retry_margin: float = 0.12
    strong: float = 0.55
    repeat: float = 0.2
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
        coarse = self._verified(fine_img, rough[:, :3])
        if len(coarse) == 0:
            return []
        circles, scores, ok = self._refined(fine_img, coarse)
        ok &= self._accepted(fine_img, circles, scores)
        circles, scores = _merge_repeats(circles[ok], scores[ok], cfg.repeat, cfg.outer_tie)
        found = [Circle(*map(float, c), float(min(s, 1.0))) for c, s in zip(circles, scores)]
        return suppress(found, cfg.strong)[: cfg.max_circles]

    def _threshold(self, circles: np.ndarray) -> np.ndarray:
        """The score each circle (N, 3) needs: ``min_score + min_score_px / r``."""
        return self.config.min_score + self.config.min_score_px / np.maximum(circles[:, 2], 1.0)

    def _verified(self, fine_img: np.ndarray, rough: np.ndarray) -> np.ndarray:
        """The candidates (N, 3) that pass the verification, as verified circles (M, 3), best first;
        repeats of one circle merged (nested circles all go on to the fine pass)."""
        cfg = self.config
        circles, scores, ok = verify_circles(fine_img, rough, cfg.verify_band, cfg.verify_edges, cfg.refine)
        r = circles[:, 2]
        ok &= scores >= cfg.verify_min_score + cfg.verify_min_score_px / np.maximum(r, 1.0)
        ok &= (r >= 0.8 * cfg.min_radius) & (r <= 1.2 * cfg.max_radius)
        order = np.argsort(-scores[ok], kind="stable")
        return _dedupe(circles[ok][order], cfg.dedupe)

    def _refined(self, fine_img: np.ndarray, coarse: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Refined circles, their scores (shares of the rays inside the image) and ok flags.

        A circle a little off a rim that a tag or a neighbour crowds converges over further passes
        (the first fits, with tight gates, hold to the rays already on the rim): circles short of
        the threshold by at most ``retry_margin`` are refined ``retries`` more times.
        """
        cfg = self.config
        shape = fine_img.shape
        circles, scores, ok = _refine_outward(fine_img, coarse, cfg.refine, cfg.min_score, cfg.outer_tie,
                                              cfg.retry_score)
        scores = _on_image_scores(circles, scores, shape, cfg.refine)
        need = self._threshold(circles)
        retry = ok & (scores < need) & (scores >= np.maximum(cfg.retry_score, need - cfg.retry_margin))
        for _ in range(cfg.retries if retry.any() else 0):
            again, again_scores, again_ok = refine_circles(fine_img, circles[retry], cfg.refine)
            again_scores = _on_image_scores(again, again_scores, shape, cfg.refine)
            better = again_ok & (again_scores > scores[retry])
            idx = np.flatnonzero(retry)[better]
            circles[idx], scores[idx] = again[better], again_scores[better]
        return circles, scores, ok

    def _accepted(self, fine_img: np.ndarray, circles: np.ndarray, scores: np.ndarray) -> np.ndarray:
        """Which circles are kept: those reaching the threshold, and weakly supported ones with a
        print inside (a node whose rim its struts and neighbours hide in part: floor texture gives
        round rims of that support, but no tag)."""
        cfg = self.config
        need = self._threshold(circles)
        weak = (scores < need) & (scores >= cfg.weak_score)
        if weak.any():
            weak[weak] = _inner_contrast(fine_img, circles[weak]) >= cfg.weak_contrast
        return (scores >= need) | weak


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


def _merge_repeats(circles: np.ndarray, scores: np.ndarray, within: float, outer_tie: float
                   ) -> tuple[np.ndarray, np.ndarray]:
    """One circle per group of repeats (centres and radii within ``within`` of the larger radius):
    taken best score first, a repeat replaces the kept circle only when it is larger and scores at
    least ``outer_tie`` of it (the rule of :func:`agents.perception.rim.keep_better`)."""
    if within <= 0 or len(circles) < 2:
        return circles, scores
    order = np.argsort(-scores, kind="stable")
    kept: list[int] = []
    for i in order:
        u, v, r = circles[i]
        for slot, j in enumerate(kept):
            big = max(r, circles[j, 2])
            if np.hypot(u - circles[j, 0], v - circles[j, 1]) < within * big and abs(r - circles[j, 2]) < within * big:
                if r > circles[j, 2] and scores[i] >= outer_tie * scores[j]:
                    kept[slot] = i
                break
        else:
            kept.append(i)
    idx = np.array(kept, dtype=int)
    return circles[idx], scores[idx]


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
        keep_better(circles, scores, again, again_scores, again_ok, min_score, outer_tie)
        ok |= again_ok
    todo = np.flatnonzero(ok & (scores >= floor))
    if len(todo):
        sub_c, sub_s = circles[todo], scores[todo]
        again, again_scores, again_ok = refine_circles(image, sub_c, cfg)
        keep_better(sub_c, sub_s, again, again_scores, again_ok, min_score, outer_tie)
        circles[todo], scores[todo] = sub_c, sub_s
    return circles, scores, ok
