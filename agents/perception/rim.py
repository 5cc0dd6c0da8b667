"""The opt-in rim detector: Hough proposals on grey and chroma, a rim found by ray votes, not the tag.

:class:`RimCircleDetector` (``detector="rim"``, ``decentral perceive --detector rim``) is a variant
of the default :class:`agents.perception.hough.HoughCircleDetector` built to report a sphere's
outline where the default fits the tag: large spheres coloured like the floor, a tag near the limb
(a concentric double circle), partly hidden spheres. Proposals also come from the Lab chroma
channels; the first pass votes on the rim radius along rays (:func:`agents.perception.rim_refine.rim_votes`)
and searches three-edge circles from off-centre proposals; only radial edges count; every circle is
also refined outward so a concentric rim outranks a circle on the tag. It costs about three times
the default's time per frame and is worse on the rendered ``table1`` frames (docs/perception.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from agents.perception.hough import HoughCircleDetector, HoughConfig, _dedupe, full_image_circles, suppress, to_grey
from agents.perception.rim_refine import RimRefineConfig, coarse_fit, refine_circles
from agents.perception.types import Circle

__all__ = ["RimConfig", "RimCircleDetector", "keep_better"]


@dataclass(frozen=True)
class RimConfig(HoughConfig):
    """Parameters of :class:`RimCircleDetector`: those of :class:`~agents.perception.hough.HoughConfig`
    (with other defaults: a 1/8 level for the largest nodes, Canny threshold 80, one radius
    multiplier, 60 proposals per level and channel, min score 0.55) and these.

    Attributes
    ----------
    chroma_param1 : float
        Canny high threshold of the proposals on the Lab chroma channels of a colour image (0: grey
        proposals only).
    weak_scores : (float, float)
        Circles scoring in this range (below ``min_score``) are kept when the image inside 0.7 of
        their radius spreads by at least ``weak_contrast`` grey levels (summed over the channels):
        a node's print (rendered table1 nodes, half their rim lost to neighbours, struts and a
        dark floor, score 0.3-0.6). The range ends at 0.5 so that no such circle reaches a log
        (``perceive --log-min-score`` 0.5): one was 7 px off a node's centre.
    weak_contrast : float
    coarse_min_score : float
        First-pass circles below this score do not reach the fine pass (its 32 rays are few: a
        partly hidden node scores low there).
    outer_tie : float
        Of the fine pass's variants of one circle, a larger one wins with at least this share of a
        smaller one's score (the isophotes inside a shaded limb are circles with radial gradients too).
    grow_multipliers : tuple of float
        Every found circle is also refined at these multiples of its radius (same centre); a
        larger rim found so outranks the nested circle in suppression.
    refine : RimRefineConfig
        Rim search and fit parameters.
    """

    levels: tuple[tuple[float, float, float], ...] = ((0.5, 8.0, 36.0), (0.25, 32.0, 80.0), (0.125, 72.0, 160.0))
    param1: float = 80.0
    chroma_param1: float = 30.0
    radius_multipliers: tuple[float, ...] = (1.0,)
    max_proposals: int = 60
    min_score: float = 0.55
    coarse_min_score: float = 0.3
    weak_scores: tuple[float, float] = (0.35, 0.5)
    weak_contrast: float = 130.0
    outer_tie: float = 0.9
    grow_multipliers: tuple[float, ...] = (1.4, 1.9, 2.5)
    refine: RimRefineConfig = field(default_factory=RimRefineConfig)


class RimCircleDetector(HoughCircleDetector):
    """Hough proposals on grey and chroma + the rim search; implements :class:`~agents.perception.types.CircleDetector`."""

    def __init__(self, config: RimConfig | None = None):
        super().__init__(config or RimConfig())

    def proposals(self, image: np.ndarray) -> np.ndarray:
        """Rough Hough circles of a uint8 image over all levels, shape (N, 3) as (u, v, r).

        On a colour (BGR) image the Hough transform also runs on the two chroma channels of CIE
        Lab (with Canny threshold ``chroma_param1``): a sphere whose brightness is close to the
        floor's often differs in hue (a red node on brown wood: 10 % of such nodes had no grey
        proposal on the varied scenes).
        """
        cfg = self.config
        colour = image.ndim == 3 and image.shape[2] == 3 and cfg.chroma_param1 > 0
        out = []
        for s, r_lo, r_hi in cfg.levels:
            lo = max(int(np.floor(max(r_lo, cfg.min_radius) * s)), 2)
            hi = int(np.ceil(min(r_hi, cfg.max_radius) * s))
            if hi <= lo:
                continue
            small = image if s == 1.0 else cv2.resize(image, None, fx=s, fy=s, interpolation=cv2.INTER_AREA)
            channels = [(to_grey(small), cfg.param1)]
            if colour:
                lab = cv2.cvtColor(small, cv2.COLOR_BGR2LAB)
                channels += [(lab[..., 1], cfg.chroma_param1), (lab[..., 2], cfg.chroma_param1)]
            for channel, param1 in channels:
                smooth = cv2.GaussianBlur(channel, (0, 0), cfg.blur) if cfg.blur > 0 else channel
                found = cv2.HoughCircles(
                    smooth, cfg.method, dp=cfg.dp, minDist=max(lo / 2.0, 2.0),
                    param1=param1, param2=cfg.param2, minRadius=lo, maxRadius=hi,
                )
                if found is None:
                    continue
                out.append(full_image_circles(found, s, cfg.max_proposals))
        return np.concatenate(out) if out else np.zeros((0, 3))

    def detect(self, image: np.ndarray) -> list[Circle]:
        """Return the refined, suppressed circles of ``image``, best score first."""
        cfg = self.config
        image = np.asarray(image)
        grey = to_grey(image)
        if grey.size == 0:
            return []
        rough = self.proposals(image)
        if len(rough) == 0:
            return []
        fine_img, hyp = self._hypotheses(image, grey, rough)
        # coarse pass on every proposal, suppression, then the fine pass on the survivors
        circles, scores, ok = coarse_fit(fine_img, hyp, cfg.refine)
        ok &= (scores >= cfg.coarse_min_score) & (circles[:, 2] >= 0.8 * cfg.min_radius) & (circles[:, 2] <= 1.2 * cfg.max_radius)
        cand = np.column_stack([circles[ok], scores[ok]])
        # only repeats of one circle are merged here (best score first); nested circles all go on
        # to the fine pass, which decides between a rim and what lies inside or around it
        coarse = _dedupe(cand[np.argsort(-cand[:, 3], kind="stable")][:, :3])
        if len(coarse) == 0:
            return []
        # each circle refined twice, with the rim as the edge nearest the coarse circle on each ray
        # (floor texture, a shadow or a neighbour just outside cannot take it) and as the outermost
        # strong edge (unbiased where the shaded limb inside the rim offers weaker edges nearer
        # to a coarse circle a little too small), then once more from the better: its score (rays
        # on the circle with a radial gradient there) decides
        circles, scores, ok = coarse[:, :3].copy(), np.zeros(len(coarse)), np.zeros(len(coarse), dtype=bool)
        for start, nearest in ((coarse[:, :3], True), (coarse[:, :3], False), (None, True)):
            if start is None:
                start = np.where(ok[:, None], circles, coarse[:, :3])
            again, again_scores, again_ok = refine_circles(fine_img, start, cfg.refine, nearest=nearest)
            keep_better(circles, scores, again, again_scores, again_ok, cfg.min_score, cfg.outer_tie)
            ok |= again_ok
        # a weakly supported circle (a node whose rim is half hidden by its neighbours, struts and
        # dark floor) is kept only with a print inside it: floor tiles and carpet give round rims of
        # that support, but a uniform inside
        weak = ok & (scores >= cfg.weak_scores[0]) & (scores < cfg.weak_scores[1])
        if weak.any():
            weak[weak] = _inner_contrast(fine_img, circles[weak]) >= cfg.weak_contrast
        ok &= (scores >= cfg.min_score) | weak
        circles, scores = circles[ok], scores[ok]
        # outward from every circle: a larger concentric rim, if one holds, is the node's (a circle
        # on the tag's square of a node whose rim is weak on its shaded side); suppression below
        # keeps the largest of nested strong circles
        if len(circles) and cfg.grow_multipliers:
            grown = np.concatenate([circles * np.array([1.0, 1.0, m]) for m in cfg.grow_multipliers])
            keep = grown[:, 2] <= cfg.max_radius * 1.2
            more, more_scores, more_ok = refine_circles(fine_img, grown[keep], cfg.refine)
            more_ok &= more_scores >= cfg.min_score
            circles = np.concatenate([circles, more[more_ok]])
            scores = np.concatenate([scores, more_scores[more_ok]])
        found = [Circle(*map(float, c), float(min(s, 1.0))) for c, s in zip(circles, scores)]
        return suppress(found, strong=0.5)[: cfg.max_circles]


def keep_better(circles: np.ndarray, scores: np.ndarray, again: np.ndarray, again_scores: np.ndarray,
                again_ok: np.ndarray, min_score: float, outer_tie: float) -> None:
    """Replace (in place) circles (N, 3) and their scores (N,) by refinements ``again`` where those
    are better. The rim is the outermost of nearly as well supported circles (inside a shaded limb
    the isophotes are circles with radial gradients too): a larger refinement wins with at least
    ``outer_tie`` of the score (and ``min_score``, or a higher score), a smaller one only with a
    score higher by more than a factor ``1 / outer_tie``."""
    wider = again[:, 2] > circles[:, 2]
    better = again_ok & np.where(wider, (again_scores >= outer_tie * scores)
                                 & ((again_scores >= min_score) | (again_scores > scores)),
                                 again_scores * outer_tie > scores)
    circles[better], scores[better] = again[better], again_scores[better]


def _inner_contrast(image: np.ndarray, circles: np.ndarray, grid: int = 9) -> np.ndarray:
    """Spread (grey levels, summed over channels) of the image on a grid inside 0.7 r of each circle, shape (N,).

    A node carries its tag (or stickers): high contrast inside; a round patch of floor does not.
    """
    t = np.linspace(-0.7, 0.7, grid, dtype=np.float32)
    gx, gy = np.meshgrid(t, t)
    inside = gx * gx + gy * gy <= 0.49
    ox, oy = gx[inside], gy[inside]
    mx = (circles[:, 0, None] + circles[:, 2, None] * ox[None, :]).astype(np.float32)
    my = (circles[:, 1, None] + circles[:, 2, None] * oy[None, :]).astype(np.float32)
    vals = cv2.remap(image, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    vals = vals.reshape(len(circles), mx.shape[1], -1)
    return vals.std(axis=1).sum(axis=1)


