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
The detector built on it is :mod:`agents.perception.symmetry_detector`.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["radius_ladder", "symmetry_candidates"]


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
