"""Identification: OpenCV's AprilTag 36h11 detector run inside each circle (Liu et al. 2024 §III-B).

Liu et al. 2024 filters AprilTag reads by the decision margin and the hamming distance. OpenCV's ArUco
module (which decodes the AprilTag families) exposes neither: it returns corners, ids and, with
``detectMarkersWithConfidence``, a confidence in [0, 1]. So each accepted read is re-measured here
from its own pixels: the tag is rectified from its corners onto the family's cell grid, each cell's
mean grey level is sampled, the black/white threshold is the midpoint of the mean grey levels of the
cells that the dictionary code says are black and white, and

- ``hamming`` = the number of data cells on the wrong side of that threshold,
- ``margin`` = min(mean(white cells) - threshold, threshold - mean(black cells)), in grey levels
  (AprilTag's decision margin is the analogous quantity of its own decoder).

A read is kept if ``hamming <= max_hamming`` and ``margin >= min_margin`` and its centre lies inside
the circle; of several, the one with the largest margin. The tag id becomes a node id through a tag
table (default: the identity, the renderer's convention).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping, Sequence

import cv2
import numpy as np

from agents.perception.hough import to_grey
from agents.perception.types import Circle, TagRead

__all__ = ["AprilTagConfig", "AprilTagIdentifier", "FAMILIES", "tag_quality"]

#: tag family name -> OpenCV predefined dictionary
FAMILIES: dict[str, int] = {
    "tag36h11": cv2.aruco.DICT_APRILTAG_36h11,
    "tag25h9": cv2.aruco.DICT_APRILTAG_25h9,
    "tag16h5": cv2.aruco.DICT_APRILTAG_16h5,
    "tag36h10": cv2.aruco.DICT_APRILTAG_36h10,
}


@dataclass(frozen=True)
class AprilTagConfig:
    """Parameters of :class:`AprilTagIdentifier`.

    Attributes
    ----------
    family : str
        Tag family, a key of :data:`FAMILIES`.
    tag_table : mapping of int to int, optional
        Tag id -> node id. None: node id = tag id. With a table, a tag it does not list is read
        (``node`` None) but names no node.
    max_hamming : int
        Largest accepted number of wrong data cells.
    min_margin : float
        Smallest accepted decision margin, grey levels.
    roi_scale : float
        The region searched around a circle is a square of half-side ``roi_scale * r``.
    target_radius : float
        Regions of circles smaller than this radius (px) are upscaled so that the circle has this
        radius, by at most ``max_upscale``: tags under about 3 px per cell decode much better so.
    max_upscale : float
        Largest upscaling factor.
    adaptive_window : int
        Single adaptive-threshold window (px, odd) of the tuned detector; None keeps OpenCV's
        default three windows (slower).
    interpolation : int
        OpenCV interpolation of the upscaling (bicubic keeps the cell edges sharper than bilinear).
    sharpen : float
        Unsharp-mask amount applied after upscaling (0: none).
    decoder : str
        ``"cells"``: OpenCV's ArUco detector finds the candidate quads (with a one-code dictionary)
        and their 8 x 8 cells are decoded here against every code of the family at once (OpenCV
        5.0's own identification against the 587 tag36h11 codes costs about 1 ms per candidate
        quad, most of a frame's identification time); ``"opencv"``: OpenCV's identification.
        Either way the read is re-measured and filtered by hamming distance and margin.

    On rendered ``multi`` frames with the true circles, the defaults read 40 % of the wholly
    visible nodes (bilinear x4 upscaling to 40 px, no sharpening: 9 %), with no wrong id.
    """

    family: str = "tag36h11"
    tag_table: Mapping[int, int] | None = None
    max_hamming: int = 2
    min_margin: float = 15.0
    roi_scale: float = 1.1
    target_radius: float = 80.0
    max_upscale: float = 6.0
    adaptive_window: int | None = 15
    interpolation: int = cv2.INTER_CUBIC
    sharpen: float = 2.0
    decoder: str = "cells"
    extra: Mapping[str, float] = field(default_factory=dict)


def _detector(cfg: AprilTagConfig) -> cv2.aruco.ArucoDetector:
    params = cv2.aruco.DetectorParameters()
    # tuned for a region that holds one node: a tag is a large part of it, so small candidate
    # squares are rejected early (the default accepts 3 % of the region's perimeter) and a single
    # threshold window suffices
    params.minMarkerPerimeterRate = 0.15
    params.maxMarkerPerimeterRate = 4.0
    params.polygonalApproxAccuracyRate = 0.05
    params.minCornerDistanceRate = 0.05
    params.minDistanceToBorder = 1
    if cfg.adaptive_window is not None:
        params.adaptiveThreshWinSizeMin = cfg.adaptive_window
        params.adaptiveThreshWinSizeMax = cfg.adaptive_window
        params.adaptiveThreshWinSizeStep = 10
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    params.cornerRefinementWinSize = 3
    # cells sampled at their centres only: a print curved over a sphere strays from the planar
    # homography most near the cell borders
    params.perspectiveRemovePixelPerCell = 8
    params.perspectiveRemoveIgnoredMarginPerCell = 0.3
    params.errorCorrectionRate = 1.0  # the re-measured hamming distance is the filter
    for name, value in cfg.extra.items():
        setattr(params, name, type(getattr(params, name))(value))
    if cfg.family not in FAMILIES:
        raise ValueError(f"unknown tag family {cfg.family!r}; known: {', '.join(FAMILIES)}")
    if cfg.decoder not in ("cells", "opencv"):
        raise ValueError(f"unknown decoder {cfg.decoder!r}; known: cells, opencv")
    dictionary = cv2.aruco.getPredefinedDictionary(FAMILIES[cfg.family])
    if cfg.decoder == "cells":  # quads only: every candidate comes back among the rejected ones
        dictionary = cv2.aruco.Dictionary(dictionary.bytesList[:1], dictionary.markerSize, 0)
        # keep nested candidates: OpenCV drops the inner of two close quads before identification,
        # and a tag printed on a sticker whose paper square contrasts with the node nests in it
        params.minMarkerDistanceRate = 0.01
    return cv2.aruco.ArucoDetector(dictionary, params)


def tag_quality(grey: np.ndarray, corners: np.ndarray, code: np.ndarray) -> tuple[int, float]:
    """Hamming distance and decision margin of one tag read, measured from its pixels.

    Parameters
    ----------
    grey : ndarray, shape (H, W), uint8
    corners : ndarray, shape (4, 2)
        Outer corners of the tag's black border, canonical order (top-left, top-right,
        bottom-right, bottom-left of the upright tag), pixels.
    code : ndarray of bool, shape (c, c)
        The dictionary's cells including the one-cell black border (True = white).

    Returns
    -------
    hamming : int
        Data cells (inside the border) on the wrong side of the black/white threshold.
    margin : float
        min(mean white - threshold, threshold - mean black), grey levels (negative when the
        cells do not separate).
    """
    cells = code.shape[0]
    px = 6  # samples per cell side
    side = cells * px
    dst = np.array([[0, 0], [side, 0], [side, side], [0, side]], np.float32) - 0.5
    H = cv2.getPerspectiveTransform(np.asarray(corners, np.float32), dst)
    warped = cv2.warpPerspective(grey, H, (side, side), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    inner = warped.reshape(cells, px, cells, px)[:, 1:-1, :, 1:-1].astype(np.float32)
    mean = inner.mean(axis=(1, 3))  # (cells, cells)
    white, black = mean[code], mean[~code]
    if white.size == 0 or black.size == 0:
        return cells * cells, -np.inf
    thr = 0.5 * (white.mean() + black.mean())
    margin = float(min(white.mean() - thr, thr - black.mean()))
    data = np.zeros_like(code)
    data[1:-1, 1:-1] = True
    hamming = int(((mean > thr) != code)[data].sum())
    return hamming, margin


class AprilTagIdentifier:
    """AprilTag reads restricted to the circles; implements :class:`~agents.perception.types.Identifier`."""

    def __init__(self, config: AprilTagConfig | None = None):
        self.config = config or AprilTagConfig()
        self._detector = _detector(self.config)
        self._dictionary = cv2.aruco.getPredefinedDictionary(FAMILIES[self.config.family])
        self._codes: dict[int, np.ndarray] = {}
        n = self._dictionary.markerSize + 2
        self._all = np.array([cv2.aruco.generateImageMarker(self._dictionary, i, n, borderBits=1) > 127
                              for i in range(self._dictionary.bytesList.shape[0])]).reshape(-1, n * n)  # (T, n*n)
        inner = np.zeros((n, n), dtype=bool)
        inner[1:-1, 1:-1] = True
        self._inner = inner.ravel()
        # per quad only these change: every code's data cells as +-1 (T, d), transposed once here,
        # and the cell order of the 4 rotations (rotation k: np.rot90(cells, -k))
        self._signs_t = np.ascontiguousarray(np.where(self._all[:, self._inner], 1.0, -1.0).T)
        self._rot = np.array([np.rot90(np.arange(n * n).reshape(n, n), -k).ravel() for k in range(4)])

    def code(self, tag: int) -> np.ndarray:
        """The cells of tag ``tag`` with its black border, shape (c, c), True = white."""
        if tag not in self._codes:
            n = self._dictionary.markerSize + 2
            self._codes[tag] = cv2.aruco.generateImageMarker(self._dictionary, int(tag), n, borderBits=1) > 127
        return self._codes[tag]

    def node_of(self, tag: int) -> int | None:
        """Node id named by tag ``tag`` (None if a tag table is set and does not list it)."""
        table = self.config.tag_table
        return int(tag) if table is None else (int(table[tag]) if tag in table else None)

    def read_region(self, grey: np.ndarray, x0: int, y0: int, x1: int, y1: int, scale: float) -> list[TagRead]:
        """Every accepted tag read in ``grey[y0:y1, x0:x1]`` (upscaled by ``scale``), image coordinates.

        ``grey`` may also be the colour (BGR/BGRA) frame: only the region is converted then.
        """
        roi = to_grey(grey[y0:y1, x0:x1])
        if roi.size == 0 or min(roi.shape) < 8:
            return []
        if self.config.sharpen > 0:
            # unsharp mask at the camera's pixel scale, before upscaling (cheaper than after):
            # restores the cell edges that the camera's blur softens
            soft = cv2.GaussianBlur(roi, (0, 0), 1.0)
            roi = cv2.addWeighted(roi, 1.0 + self.config.sharpen, soft, -self.config.sharpen, 0.0)
        if scale != 1.0:
            roi = cv2.resize(roi, None, fx=scale, fy=scale, interpolation=self.config.interpolation)
        if self.config.decoder == "cells":
            found = self._decode_quads(roi)
        else:
            corners, ids, conf, _ = self._detector.detectMarkersWithConfidence(roi)
            if ids is None or len(ids) == 0:
                return []
            found = [(np.asarray(c, dtype=float).reshape(4, 2), int(t), float(cf))
                     for c, t, cf in zip(corners, np.asarray(ids).ravel(), np.asarray(conf).ravel())]
        out = []
        for c, tag, cf in found:
            hamming, margin = tag_quality(roi, c, self.code(int(tag)))
            if hamming > self.config.max_hamming or margin < self.config.min_margin:
                continue
            # a resized pixel centre k sits at (k + 0.5) / scale - 0.5 in the region
            full = (c + 0.5) / scale - 0.5 + np.array([x0, y0])
            out.append(TagRead(int(tag), self.node_of(int(tag)), full, hamming, margin, float(cf)))
        return out

    def _decode_quads(self, roi: np.ndarray) -> list[tuple[np.ndarray, int, float]]:
        """Candidate quads of ``roi`` decoded against every code: (corners (4, 2), tag, confidence).

        Each quad's cells are sampled at their centres for its 4 rotations (OpenCV returns the
        corners of every candidate in one winding); the data cells, thresholded at the midpoint of
        the border's and the brightest cells' grey levels, are matched against every code at once,
        and the few best matches are re-scored as in :func:`tag_quality` (threshold between the
        code's own white and black cell means). The best (fewest wrong data cells, then widest
        margin) is kept if its hamming distance passes; its corners are refined to sub-pixel
        (``cv2.cornerSubPix``, as OpenCV's own CORNER_REFINE_SUBPIX) in canonical order.
        """
        corners, ids, rejected = self._detector.detectMarkers(roi)
        quads = list(rejected or ()) + list(corners or ())
        n = self._dictionary.markerSize + 2
        px = 4
        side = n * px
        dst = np.array([[0, 0], [side, 0], [side, side], [0, side]], np.float32) - 0.5
        codes, inner = self._all, self._inner
        out = []
        for q in quads:
            q = np.asarray(q, dtype=np.float32).reshape(4, 2)
            if cv2.contourArea(q) < 4.0 * n * n:  # under 2 px per cell: nothing to decode
                continue
            warped = cv2.warpPerspective(roi, cv2.getPerspectiveTransform(q, dst), (side, side),
                                         flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            cells = warped.reshape(n, px, n, px)[:, 1:-1, :, 1:-1].astype(np.float32).mean(axis=(1, 3))
            m = cells.ravel()[self._rot]  # (4, n*n); rotation k: the tag starts at corner -k
            border = m[:, ~inner].mean(axis=1)
            bright = np.sort(m[:, inner], axis=1)[:, -6:].mean(axis=1)
            thr0 = 0.5 * (border + bright)
            agree = np.where(m[:, inner] > thr0[:, None], 1.0, -1.0) @ self._signs_t  # (4, T)
            ham0 = ((inner.sum() - agree) / 2.0).ravel()
            # the 4 best (rotation, tag) pairs, fewest wrong cells first, re-scored all at once
            few = np.argpartition(ham0, 3)[:4]
            few = few[np.argsort(ham0[few], kind="stable")]
            ks, tags = np.unravel_index(few, agree.shape)
            code, mk = codes[tags], m[ks]  # (4, n*n)
            white = (mk * code).sum(axis=1) / code.sum(axis=1)
            black = (mk * ~code).sum(axis=1) / (~code).sum(axis=1)
            thr = 0.5 * (white + black)
            margins = np.minimum(white - thr, thr - black)
            hams = (((mk > thr[:, None]) != code) & inner).sum(axis=1)
            j = int(np.lexsort((-margins, hams))[0])  # fewest wrong cells, then widest margin
            ham, margin, k, tag = int(hams[j]), float(margins[j]), int(ks[j]), int(tags[j])
            if ham > self.config.max_hamming or margin <= 0:
                continue
            c = cv2.cornerSubPix(roi, np.roll(q, k, axis=0).reshape(-1, 1, 2).copy(), (3, 3), (-1, -1),
                                 (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 0.01)).reshape(4, 2)
            out.append((c.astype(float), int(tag), float(1.0 - ham / inner.sum())))
        return out

    def identify(self, image: np.ndarray, circles: Sequence[Circle]) -> list[TagRead | None]:
        """One accepted read per circle (the largest margin among reads centred inside it) or None."""
        grey = np.asarray(image)  # converted to grey region by region (read_region)
        if grey.ndim not in (2, 3):
            raise ValueError(f"expected a (H, W), (H, W, 3) or (H, W, 4) image, got shape {grey.shape}")
        h, w = grey.shape[:2]
        out: list[TagRead | None] = []
        for circle in circles:
            half = self.config.roi_scale * circle.r
            x0, x1 = max(int(np.floor(circle.u - half)), 0), min(int(np.ceil(circle.u + half)) + 1, w)
            y0, y1 = max(int(np.floor(circle.v - half)), 0), min(int(np.ceil(circle.v + half)) + 1, h)
            scale = float(np.clip(self.config.target_radius / max(circle.r, 1.0), 1.0, self.config.max_upscale))
            best = None
            for read in self.read_region(grey, x0, y0, x1, y1, scale):
                centre = read.corners.mean(axis=0)
                if np.hypot(centre[0] - circle.u, centre[1] - circle.v) > circle.r:
                    continue
                if best is None or read.margin > best.margin:
                    best = read
            out.append(best)
        return out
