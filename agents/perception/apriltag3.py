"""Identification with the AprilTag 3 C library run inside each circle (Liu et al. 2024 §III-B).

Liu et al. 2024 read the AprilTag inside each detected circle and keep reads by decision margin and
hamming distance. :class:`AprilTag3Identifier` does that with the AprilTag 3 library itself (Wang and
Olson 2016; Krogius et al. 2019) through its ``pupil-apriltags`` binding: the square of half-side
``roi_scale * r`` around each circle, in grey, upscaled so that small circles reach
``target_radius`` px, is searched, and a read is kept when its hamming distance is at most
``max_hamming``, its decision margin (the library's own) at least ``min_margin`` and its centre
inside the circle (of several, the largest margin). Circles it reads nothing in go to the
``fallback`` identifier, by default OpenCV's quads decoded per cell
(:class:`~agents.perception.apriltag.AprilTagIdentifier`), which reads some small, blurred prints
the library misses (docs/perception.md gives the measured shares).

Corners come in the canonical order of :class:`~agents.perception.types.TagRead` (top-left,
top-right, bottom-right, bottom-left of the upright tag; the library's own order is top-right,
top-left, bottom-left, bottom-right).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from agents.perception.apriltag import AprilTagConfig, AprilTagIdentifier
from agents.perception.hough import to_grey
from agents.perception.types import Circle, Identifier, TagRead

__all__ = ["AprilTag3Config", "AprilTag3Identifier", "apriltag3_available", "make_identifier", "AT3_FAMILIES"]

_ORDER = np.array([1, 0, 3, 2])  # the library's corners -> TL, TR, BR, BL
#: the families of :data:`~agents.perception.apriltag.FAMILIES` the library decodes (not tag36h10)
AT3_FAMILIES = ("tag36h11", "tag25h9", "tag16h5")


def apriltag3_available() -> bool:
    """Whether the AprilTag 3 binding (``pupil-apriltags``) imports."""
    try:
        import pupil_apriltags  # noqa: F401
    except ImportError:
        return False
    return True


@dataclass(frozen=True)
class AprilTag3Config:
    """Parameters of :class:`AprilTag3Identifier`.

    Attributes
    ----------
    family : str
        Tag family, one of :data:`AT3_FAMILIES`.
    tag_table : mapping of int to int, optional
        Tag id -> node id (default: node id = tag id).
    max_hamming : int
        Largest accepted number of corrected bits.
    min_margin : float
        Smallest accepted decision margin (the library's, grey levels).
    roi_scale : float
        Half-side of the searched square in circle radii.
    target_radius, max_upscale : float
        Regions of circles under ``target_radius`` px are upscaled (bicubic) by up to ``max_upscale``.
    decode_sharpening : float
        The library's sharpening of the decoded cells.
    fallback : bool
        Hand circles without a read to OpenCV's per-cell decoder.
    """

    family: str = "tag36h11"
    tag_table: Mapping[int, int] | None = None
    max_hamming: int = 2
    min_margin: float = 15.0
    roi_scale: float = 1.1
    target_radius: float = 40.0
    max_upscale: float = 3.0
    decode_sharpening: float = 0.25
    fallback: bool = True


class AprilTag3Identifier:
    """AprilTag 3 reads restricted to the circles; implements :class:`~agents.perception.types.Identifier`."""

    def __init__(self, config: AprilTag3Config | None = None, fallback: Identifier | None = None):
        from pupil_apriltags import Detector

        self.config = cfg = config or AprilTag3Config()
        if cfg.family not in AT3_FAMILIES:
            raise ValueError(f"unknown tag family {cfg.family!r} for AprilTag 3; known: {', '.join(AT3_FAMILIES)}")
        self._detector = Detector(families=cfg.family, nthreads=1, quad_decimate=1.0, refine_edges=1,
                                  decode_sharpening=cfg.decode_sharpening)
        self.fallback = (fallback or AprilTagIdentifier(AprilTagConfig(family=cfg.family, tag_table=cfg.tag_table))) \
            if cfg.fallback else None

    def close(self) -> None:
        """Free the C detector and its families, in an order that is safe.

        pupil-apriltags 1.0.4's own destructor frees the families first and then the detector, whose
        destructor reads them again (a use after free that crashed a benchmark): here the families
        are unregistered from the detector first.
        """
        d = getattr(self, "_detector", None)
        if d is None or getattr(d, "tag_detector_ptr", None) is None:
            return
        for fn in ("apriltag_detector_clear_families", "apriltag_detector_destroy"):
            getattr(d.libc, fn).restype = None
        d.libc.apriltag_detector_clear_families(d.tag_detector_ptr)
        for family, tf in d.tag_families.items():
            destroy = getattr(d.libc, f"{family}_destroy")
            destroy.restype = None
            destroy(tf)
        d.libc.apriltag_detector_destroy(d.tag_detector_ptr)
        d.tag_detector_ptr = None

    def __del__(self):
        self.close()

    def node_of(self, tag: int) -> int | None:
        """Node id named by tag ``tag`` (None if a tag table is set and does not list it)."""
        table = self.config.tag_table
        return int(tag) if table is None else (int(table[tag]) if tag in table else None)

    def _read(self, image: np.ndarray, circle: Circle) -> TagRead | None:
        cfg = self.config
        h, w = image.shape[:2]
        half = cfg.roi_scale * circle.r
        x0, x1 = max(int(np.floor(circle.u - half)), 0), min(int(np.ceil(circle.u + half)) + 1, w)
        y0, y1 = max(int(np.floor(circle.v - half)), 0), min(int(np.ceil(circle.v + half)) + 1, h)
        if x1 - x0 < 8 or y1 - y0 < 8:
            return None
        roi = to_grey(image[y0:y1, x0:x1])
        scale = float(np.clip(cfg.target_radius / max(circle.r, 1.0), 1.0, cfg.max_upscale))
        if scale != 1.0:
            roi = cv2.resize(roi, None, fx=scale, fy=scale, interpolation=cv2.INTER_CUBIC)
        best = None
        for t in self._detector.detect(np.ascontiguousarray(roi)):
            if t.hamming > cfg.max_hamming or t.decision_margin < cfg.min_margin:
                continue
            corners = (np.asarray(t.corners, float)[_ORDER] + 0.5) / scale - 0.5 + np.array([x0, y0])
            centre = corners.mean(axis=0)
            if np.hypot(centre[0] - circle.u, centre[1] - circle.v) > circle.r:
                continue
            if best is None or t.decision_margin > best.margin:
                best = TagRead(int(t.tag_id), self.node_of(int(t.tag_id)), corners, int(t.hamming),
                               float(t.decision_margin), 1.0 - t.hamming / 36.0)
        return best

    def identify(self, image: np.ndarray, circles: Sequence[Circle],
                 fallback: Sequence[bool] | None = None) -> list[TagRead | None]:
        """One accepted read per circle, or None.

        ``fallback`` (bool per circle, optional): which circles the library reads nothing in may go
        to the fallback reader (default all; :class:`~agents.perception.pipeline.Perception` spares
        it the circles whose tracked id no read can change).
        """
        img = np.asarray(image)
        if img.ndim not in (2, 3):
            raise ValueError(f"expected a (H, W), (H, W, 3) or (H, W, 4) image, got shape {img.shape}")
        if fallback is not None and len(fallback) != len(circles):
            raise ValueError("fallback must hold one flag per circle")
        out = [self._read(img, c) for c in circles]
        if self.fallback is not None:
            missing = [i for i, r in enumerate(out) if r is None and (fallback is None or fallback[i])]
            if missing:
                for i, r in zip(missing, self.fallback.identify(img, [circles[i] for i in missing])):
                    out[i] = r
        return out


def make_identifier(family: str = "tag36h11", tag_table: Mapping[int, int] | None = None) -> Identifier:
    """The default tag reader: :class:`AprilTag3Identifier` (OpenCV's reader as its fallback), or
    OpenCV's :class:`~agents.perception.apriltag.AprilTagIdentifier` alone where ``pupil-apriltags``
    is not installed or the family is not one of :data:`AT3_FAMILIES` (tag36h10). Raises ValueError
    for an unknown family."""
    if apriltag3_available() and family in AT3_FAMILIES:
        return AprilTag3Identifier(AprilTag3Config(family=family, tag_table=tag_table))
    return AprilTagIdentifier(AprilTagConfig(family=family, tag_table=tag_table))
