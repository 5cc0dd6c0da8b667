"""The classical default circle detector: OpenCV Hough circles, sub-pixel refinement, suppression.

Liu et al. 2024 §III-A detects nodes as bounding circles with a learned detector; this default needs no
training: ``cv2.HoughCircles`` proposes rough circles on a smoothed image (generously: false
proposals are cheap), each is refined to sub-pixel accuracy and scored by
:func:`agents.perception.refine.refine_circles`,
and overlapping proposals are suppressed (duplicates, and circles whose centre lies inside a larger,
better circle: a node of the same physical size that looks smaller is farther, so its centre cannot
be visible through a nearer one).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from agents.perception.heap import keep_freed_memory
from agents.perception.refine import RefineConfig, coarse_fit, refine_circles
from agents.perception.types import Circle

__all__ = ["HoughConfig", "HoughCircleDetector", "full_image_circles", "to_grey"]


def to_grey(image: np.ndarray) -> np.ndarray:
    """Return ``image`` as a (H, W) uint8 grey image (accepts grey, BGR or BGRA uint8)."""
    if image.ndim == 2:
        return image
    if image.ndim == 3 and image.shape[2] == 3:
        return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    if image.ndim == 3 and image.shape[2] == 4:
        return cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY)
    raise ValueError(f"expected a (H, W), (H, W, 3) or (H, W, 4) image, got shape {image.shape}")


@dataclass(frozen=True)
class HoughConfig:
    """Parameters of :class:`HoughCircleDetector`.

    Attributes
    ----------
    method : int
        ``cv2.HOUGH_GRADIENT`` (default: fast, many proposals) or ``cv2.HOUGH_GRADIENT_ALT``.
    levels : tuple of (scale, r_lo, r_hi)
        Pyramid levels of the proposal stage: circles of full-resolution radius in [r_lo, r_hi] are
        sought on the image resized by ``scale`` (proposals are only rough; the refinement runs at
        full resolution). The Hough cost grows with the radius range in pixels, so large circles are
        sought on coarser levels, and coarse levels blur the stickers' squares away.
    blur : float
        Gaussian sigma (px, at each level's scale) before the Hough transform.
    dp, param1, param2 : float
        ``cv2.HoughCircles`` accumulator resolution, Canny high threshold and accumulator threshold
        (``HOUGH_GRADIENT``; for ``HOUGH_GRADIENT_ALT`` param2 is the circle "perfectness" in (0, 1)).
    max_proposals : int
        At most this many proposals (strongest accumulator first) are refined.
    radius_multipliers : tuple of float
        Each proposal is refined from these multiples of its radius (the best survives suppression).
    min_radius, max_radius : int
        Radius range in pixels of the returned circles (the levels should cover it).
    refine_blur : float
        Gaussian sigma (px) of the image the rim search runs on.
    min_score : float
        Circles whose refined rim support is below this are dropped.
    max_circles : int
        At most this many circles are returned (best score first).
    refine : RefineConfig
        Rim search and fit parameters.
    """

    levels: tuple[tuple[float, float, float], ...] = ((0.5, 8.0, 36.0), (0.25, 32.0, 160.0))
    method: int = cv2.HOUGH_GRADIENT
    blur: float = 1.0
    dp: float = 1.5
    param1: float = 150.0
    param2: float = 15.0
    radius_multipliers: tuple[float, ...] = (1.0, 1.35, 2.2)
    max_proposals: int = 120
    min_radius: int = 8
    max_radius: int = 160
    refine_blur: float = 1.0
    min_score: float = 0.3
    max_circles: int = 64
    refine: RefineConfig = field(default_factory=RefineConfig)


def full_image_circles(found: np.ndarray, scale: float, max_proposals: int) -> np.ndarray:
    """The first ``max_proposals`` circles of a ``cv2.HoughCircles`` result on an image resized by
    ``scale``, as (N, 3) (u, v, r) in full-image pixels (a resized pixel centre k sits at
    (k + 0.5) / scale - 0.5 in the full image)."""
    rough = found[0, :max_proposals, :3].astype(float)
    rough[:, :2] = (rough[:, :2] + 0.5) / scale - 0.5
    rough[:, 2] /= scale
    return rough


class HoughCircleDetector:
    """Hough proposals + sub-pixel rim refinement; implements :class:`~agents.perception.types.CircleDetector`."""

    def __init__(self, config: HoughConfig | None = None):
        self.config = config or HoughConfig()
        # the blurred frame (9.4 MB at 1024 x 768 x 3 float32) is written into the same buffer
        # every frame: a fresh one is a fresh mmap whose pages fault in again, which cost ~7 ms of
        # CPU per frame once the allocator began returning memory to the system between frames
        self._fine: np.ndarray | None = None
        keep_freed_memory()  # the same for the many per-frame arrays (see agents.perception.heap)

    def proposals(self, grey: np.ndarray) -> np.ndarray:
        """Rough Hough circles of a grey uint8 image over all levels, shape (N, 3) as (u, v, r)."""
        cfg = self.config
        out = []
        for s, r_lo, r_hi in cfg.levels:
            small = grey if s == 1.0 else cv2.resize(grey, None, fx=s, fy=s, interpolation=cv2.INTER_AREA)
            smooth = cv2.GaussianBlur(small, (0, 0), cfg.blur) if cfg.blur > 0 else small
            lo = max(int(np.floor(max(r_lo, cfg.min_radius) * s)), 2)
            hi = int(np.ceil(min(r_hi, cfg.max_radius) * s))
            if hi <= lo:
                continue
            found = cv2.HoughCircles(
                smooth, cfg.method, dp=cfg.dp, minDist=max(lo / 2.0, 2.0),
                param1=cfg.param1, param2=cfg.param2, minRadius=lo, maxRadius=hi,
            )
            if found is None:
                continue
            out.append(full_image_circles(found, s, cfg.max_proposals))
        return np.concatenate(out) if out else np.zeros((0, 3))

    def _hypotheses(self, image: np.ndarray, grey: np.ndarray, rough: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The blurred float image the rim search runs on, and the circles (M, 3) it tries for ``rough``.

        The rim search runs on the colour image when there is one (chroma edges count too), blurred in
        float: blurring the uint8 image is faster but its rounding to whole grey levels cost accuracy
        downstream (table1 experiment: 0.039 -> 0.065 m with confident placement). Each proposal also
        stands for larger circles (``radius_multipliers``): a proposal that locked onto the square
        sticker inside a node (0.35-0.5 of its radius) or onto its lit side then still finds the rim.
        """
        cfg = self.config
        src = image if image.ndim == 3 and image.shape[2] == 3 else grey
        if self._fine is None or self._fine.shape != src.shape:
            self._fine = np.empty(src.shape, np.float32)
        fine_img = _blur_float(src, cfg.refine_blur, out=self._fine)
        rough = _dedupe(rough)
        hyp = np.concatenate([rough * np.array([1.0, 1.0, m]) for m in cfg.radius_multipliers])
        return fine_img, hyp[hyp[:, 2] <= cfg.max_radius * 1.2]

    def detect(self, image: np.ndarray) -> list[Circle]:
        """Return the refined, suppressed circles of ``image``, best score first."""
        cfg = self.config
        grey = to_grey(np.asarray(image))
        if grey.size == 0:
            return []
        rough = self.proposals(grey)
        if len(rough) == 0:
            return []
        image = np.asarray(image)
        fine_img, hyp = self._hypotheses(image, grey, rough)
        # coarse pass on every proposal, suppression, then the fine pass on the survivors
        circles, scores, ok = coarse_fit(fine_img, hyp, cfg.refine)
        ok &= (scores >= cfg.min_score) & (circles[:, 2] >= 0.8 * cfg.min_radius) & (circles[:, 2] <= 1.2 * cfg.max_radius)
        cand = np.column_stack([circles[ok], scores[ok]])
        coarse = cand[_suppress_order(cand)]
        if len(coarse) == 0:
            return []
        circles, scores, ok = refine_circles(fine_img, coarse[:, :3], cfg.refine)
        ok &= scores >= cfg.min_score
        found = [Circle(*map(float, c), float(min(s, 1.0))) for c, s in zip(circles[ok], scores[ok])]
        return suppress(found)[: cfg.max_circles]


def _blur_float(image: np.ndarray, sigma: float, out: np.ndarray | None = None) -> np.ndarray:
    """``image`` (uint8 or float) as float32, Gaussian-blurred with ``sigma`` px (0: none).

    The same kernel as ``cv2.GaussianBlur`` on the float image (size ``2 ceil(4 sigma) + 1``), applied
    straight from uint8 to float32 by ``sepFilter2D``: no float copy of the frame is blurred, and no
    rounding to whole grey levels happens (about half the cost of converting and then blurring).
    ``out`` (float32, the image's shape), if given, receives the result.
    """
    if sigma <= 0:
        if out is None:
            return image.astype(np.float32)
        out[...] = image
        return out
    size = 2 * int(np.ceil(4.0 * sigma)) + 1
    k = cv2.getGaussianKernel(size, sigma).astype(np.float32)
    if out is None:
        return cv2.sepFilter2D(image, cv2.CV_32F, k, k)
    return cv2.sepFilter2D(image, cv2.CV_32F, k, k, dst=out)


def _dedupe(rough: np.ndarray, within: float = 0.15) -> np.ndarray:
    """Drop proposals within ``within`` of an earlier (stronger) one's radius in centre and radius."""
    d = np.hypot(rough[:, None, 0] - rough[None, :, 0], rough[:, None, 1] - rough[None, :, 1])
    big = np.maximum(rough[:, None, 2], rough[None, :, 2])
    close = (d < within * big) & (np.abs(rough[:, None, 2] - rough[None, :, 2]) < within * big)
    keep = ~np.triu(close, k=1).T.any(axis=1)  # i is dropped if some j < i is close to it
    return rough[keep]


def suppress(circles: list[Circle], strong: float = 0.45) -> list[Circle]:
    """Greedy suppression of nested and duplicate circles; return the kept ones, best score first.

    Two circles clash when the centre of one lies inside the other. Nodes share one physical size,
    so of two nested circles the smaller is either not a node (the circle inscribed in a node's
    square sticker) or a farther node whose centre the nearer one hides: strong circles (score >=
    ``strong``) are therefore kept largest first, then the weaker ones best score first, each only
    if it clashes with nothing kept.
    """
    if not circles:
        return []
    arr = np.array([[c.u, c.v, c.r, c.score] for c in circles], dtype=float)
    return [circles[i] for i in _suppress_order(arr, strong)]


def _suppress_order(arr: np.ndarray, strong: float = 0.45) -> list[int]:
    """:func:`suppress` on an (N, 4) array of (u, v, r, score): the kept rows' indices, best score first."""
    if len(arr) == 0:
        return []
    r, score = arr[:, 2], arr[:, 3]
    first = np.flatnonzero(score >= strong)
    then = np.flatnonzero(score < strong)
    # stable sorts, ties in input order (as Python's sorted)
    first = first[np.lexsort((-score[first], -r[first]))]
    then = then[np.lexsort((-r[then], -score[then]))]
    order = np.concatenate([first, then])
    a = arr[order]
    clash = np.hypot(a[:, None, 0] - a[None, :, 0], a[:, None, 1] - a[None, :, 1]) < 0.9 * np.maximum(
        a[:, None, 2], a[None, :, 2])
    keep = np.zeros(len(order), dtype=bool)
    for i in range(len(order)):
        if not (clash[i] & keep).any():
            keep[i] = True
    kept = order[keep]
    return [int(i) for i in kept[np.argsort(-score[kept], kind="stable")]]
