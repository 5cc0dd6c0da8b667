"""Conformance checks of the perception plug-ins: :func:`detector_test`, :func:`identifier_test`, :func:`tracker_test`.

Each drives one object through the contract of its protocol (:class:`~agents.perception.types.CircleDetector`,
:class:`~agents.perception.types.Identifier`, :class:`~agents.perception.types.Tracker`) on small
synthetic images and raises :class:`AssertionError` with a message saying what to fix at the first
broken rule, in the manner of PettingZoo's ``parallel_api_test``. docs/conformance.md shows how to
check your own detector, identifier or tracker.
"""

from __future__ import annotations

import math
from typing import Any, Sequence

import cv2
import numpy as np

from agents.perception.types import Circle, TagRead, TrackedCircle

__all__ = ["disc_image", "detector_test", "identifier_test", "tag_image", "tracker_test"]


def _require(ok: bool, who: str, message: str) -> None:
    if not ok:
        raise AssertionError(f"{who}: {message}")


def disc_image(size: tuple[int, int] = (320, 240), discs: Sequence[tuple[float, float, float]] = ((150.3, 110.7, 30.0),),
               *, background: int = 30, foreground: int = 210) -> np.ndarray:
    """A grey (H, W) uint8 image of bright anti-aliased discs ``(u, v, r)`` (pixels) on a dark background."""
    w, h = size
    y, x = np.mgrid[0:h, 0:w].astype(float)
    alpha = np.zeros((h, w))
    for u, v, r in discs:
        alpha = np.maximum(alpha, np.clip(r - np.hypot(x - u, y - v) + 0.5, 0.0, 1.0))
    return (background + (foreground - background) * alpha).astype(np.uint8)


def tag_image(tag: int = 7, *, size: tuple[int, int] = (320, 240), centre: tuple[float, float] = (160.0, 120.0),
              radius: float = 60.0, family: int = cv2.aruco.DICT_APRILTAG_36h11) -> tuple[np.ndarray, Circle]:
    """A grey image of a white disc holding an upright flat AprilTag ``tag``, and the disc's circle."""
    w, h = size
    img = np.full((h, w), 90, np.uint8)
    cv2.circle(img, (int(round(centre[0])), int(round(centre[1]))), int(round(radius)), 235, -1, cv2.LINE_AA)
    side = int(radius * 1.1)
    marker = cv2.aruco.generateImageMarker(cv2.aruco.getPredefinedDictionary(family), int(tag), side, borderBits=1)
    x0, y0 = int(round(centre[0] - side / 2)), int(round(centre[1] - side / 2))
    img[y0:y0 + side, x0:x0 + side] = marker
    return img, Circle(float(centre[0]), float(centre[1]), float(radius), 1.0)


def _check_circles(circles: Any, who: str, what: str) -> list[Circle]:
    _require(isinstance(circles, list), who, f"detect({what}) returned {type(circles).__name__}, not a list of Circle")
    for c in circles:
        _require(isinstance(c, Circle), who, f"detect({what}) returned a {type(c).__name__} in its list, not a Circle")
        _require(all(math.isfinite(x) for x in (c.u, c.v, c.r, c.score)) and c.r > 0, who,
                 f"detect({what}) returned {c}: u, v, r and score must be finite and r > 0 (never NaN)")
        _require(0.0 <= c.score <= 1.0, who, f"detect({what}) returned score {c.score}: scores lie in [0, 1]")
    return circles


def detector_test(det: Any, *, size: tuple[int, int] = (320, 240), radius: float = 30.0,
                  centre_tol: float = 2.0, radius_tol: float = 0.1) -> None:
    """Check that ``det`` behaves as a :class:`~agents.perception.types.CircleDetector`; raise ``AssertionError`` if not.

    The rules: ``detect`` takes grey (H, W) and BGR (H, W, 3) uint8 images and returns a list of
    :class:`~agents.perception.types.Circle` with finite centres, positive radii and scores in [0, 1];
    it finds nothing on a uniform image; on a bright disc of ``radius`` px it returns a circle within
    ``centre_tol`` px and ``radius_tol`` (relative) of it, first or among equals; the grey and BGR
    versions of one image give the same circles; it leaves the image untouched; and the same image
    gives the same answer twice.

    Parameters
    ----------
    det : object
        The detector, configured for circles of ``radius`` px in ``size`` (width, height) images.
    size : (int, int)
        Width and height of the test images.
    radius, centre_tol, radius_tol : float
        The disc's radius (px) and the accuracy asked for.

    Examples
    --------
    >>> from agents.perception import HoughCircleDetector
    >>> detector_test(HoughCircleDetector())  # passes: returns None
    """
    who = f"detector_test({type(det).__name__})"
    _require(callable(getattr(det, "detect", None)), who, "has no detect(image) method")
    w, h = size
    blank = np.full((h, w), 128, np.uint8)
    _require(_check_circles(det.detect(blank), who, "uniform grey image") == [], who,
             "found circles on a uniform image; accept a circle only where the image shows one")
    u, v = 0.47 * w + 0.3, 0.46 * h + 0.7
    grey = disc_image(size, ((u, v, radius),))
    before = grey.copy()
    circles = _check_circles(det.detect(grey), who, "grey disc image")
    _require(np.array_equal(grey, before), who, "detect() modified the image it was given; work on a copy")
    near = [c for c in circles if math.hypot(c.u - u, c.v - v) <= centre_tol and abs(c.r - radius) <= radius_tol * radius]
    _require(bool(near), who, f"missed the disc at ({u:.1f}, {v:.1f}) of radius {radius} px (found "
             f"{[(round(c.u, 1), round(c.v, 1), round(c.r, 1)) for c in circles]}); check the radius range it is "
             f"configured for and that it reports centres in pixels of the given image")
    best = max(c.score for c in circles)
    _require(near[0].score >= best - 1e-9, who, "the disc's circle does not carry the highest score: return best first")
    again = det.detect(grey)
    _require(again == circles, who, "two calls on the same image differ: detect() must be deterministic")
    bgr = np.repeat(grey[:, :, None], 3, axis=2)
    colour = _check_circles(det.detect(bgr), who, "BGR disc image")
    _require(len(colour) == len(circles) and all(math.hypot(a.u - b.u, a.v - b.v) <= 0.5 and abs(a.r - b.r) <= 0.5
                                                   for a, b in zip(colour, circles)), who,
             "a BGR image with three equal channels gives other circles than its grey version; convert BGR "
             "input to grey (agents.perception.hough.to_grey) or treat both alike")


def identifier_test(ident: Any, *, reads_flat_tags: bool = True, tag: int = 7) -> None:
    """Check that ``ident`` behaves as an :class:`~agents.perception.types.Identifier`; raise ``AssertionError`` if not.

    The rules: ``identify(image, circles)`` returns a list with one entry per circle, in order, each
    None or a :class:`~agents.perception.types.TagRead` with an int tag, finite (4, 2) corners, a
    Hamming distance >= 0 and a confidence in [0, 1]; no circles give an empty list; a circle on a
    uniform image reads as None; it leaves the image untouched; and it is deterministic. With
    ``reads_flat_tags`` it must also read tag ``tag`` of the AprilTag 36h11 family printed flat in a
    disc (:func:`tag_image`); identifiers of tags on curved spheres set it False.

    Examples
    --------
    >>> from agents.perception import AprilTagIdentifier
    >>> identifier_test(AprilTagIdentifier())  # passes: returns None
    """
    who = f"identifier_test({type(ident).__name__})"
    _require(callable(getattr(ident, "identify", None)), who, "has no identify(image, circles) method")
    img, circle = tag_image(tag)
    _require(ident.identify(img, []) == [], who, "identify(image, []) must return an empty list")
    blank = np.full_like(img, 128)
    out = ident.identify(blank, [circle])
    _require(isinstance(out, list) and len(out) == 1, who,
             f"identify() with one circle returned {out!r}: return a list with one entry per circle")
    _require(out[0] is None, who, "read a tag on a uniform image; return None where no tag is read")
    decoy = Circle(40.0, 40.0, 20.0, 0.5)
    before = img.copy()
    reads = ident.identify(img, [decoy, circle])
    _require(np.array_equal(img, before), who, "identify() modified the image it was given; work on a copy")
    _require(isinstance(reads, list) and len(reads) == 2, who,
             f"identify() with two circles returned {len(reads) if isinstance(reads, list) else reads!r} entries")
    for r in reads:
        if r is None:
            continue
        _require(isinstance(r, TagRead), who, f"returned a {type(r).__name__}, not a TagRead or None")
        corners = np.asarray(r.corners)
        _require(isinstance(r.tag, (int, np.integer)) and corners.shape == (4, 2) and bool(np.all(np.isfinite(corners))),
                 who, f"a TagRead needs an int tag and finite (4, 2) corners, got tag {r.tag!r}, corners {corners.shape}")
        _require(r.hamming >= 0 and 0.0 <= r.confidence <= 1.0, who,
                 f"a TagRead needs hamming >= 0 and confidence in [0, 1], got {r.hamming}, {r.confidence}")
    if reads_flat_tags:
        _require(reads[1] is not None and int(reads[1].tag) == tag, who,
                 f"did not read tag {tag} printed flat inside the second circle (got {reads[1]!r}); pass "
                 f"reads_flat_tags=False for an identifier of tags on curved spheres")
    again = ident.identify(img, [decoy, circle])
    same = all((a is None and b is None) or (a is not None and b is not None and a.tag == b.tag
                                             and np.array_equal(a.corners, b.corners)) for a, b in zip(reads, again))
    _require(same, who, "two calls on the same input differ: identify() must be deterministic")


def _tracked(out: Any, circles: Sequence[Circle], who: str, frame: int) -> list[TrackedCircle]:
    _require(isinstance(out, list) and len(out) == len(circles), who,
             f"frame {frame}: update() must return one TrackedCircle per input circle, got "
             f"{len(out) if isinstance(out, list) else type(out).__name__}")
    for t, c in zip(out, circles):
        _require(isinstance(t, TrackedCircle), who, f"frame {frame}: returned a {type(t).__name__}, not a TrackedCircle")
        _require(t.circle == c, who, f"frame {frame}: entries must follow the input order and carry the input circle")
    return out


def tracker_test(tracker: Any, *, frames: int = 6) -> None:
    """Check that ``tracker`` behaves as a :class:`~agents.perception.types.Tracker`; raise ``AssertionError`` if not.

    The rules: after ``reset()``, ``update(circles, reads, motion=...)`` returns one
    :class:`~agents.perception.types.TrackedCircle` per input circle, in order; an empty frame gives an
    empty list; on two discs that move slowly (half a radius per frame), each read once at the first
    frame and never again, the node ids carry through the drop-outs and each disc keeps its track id
    once given (a tracker may leave new tracks without an id for a few frames);
    an identity ``motion`` changes nothing; and ``reset()`` then the same frames give the same output.

    Examples
    --------
    >>> from agents.perception import CircleTracker
    >>> tracker_test(CircleTracker())  # passes: returns None
    """
    who = f"tracker_test({type(tracker).__name__})"
    for method in ("update", "reset"):
        _require(callable(getattr(tracker, method, None)), who, f"has no {method}() method")

    tracker.reset()
    _require(tracker.update([], []) == [], who, "update([], []) must return an empty list")

    def sequence(motion: np.ndarray | None) -> list[list[TrackedCircle]]:
        tracker.reset()
        outs = []
        for k in range(frames):
            circles = [Circle(100.0 + 5.0 * k, 120.0, 20.0, 0.9), Circle(220.0, 80.0 + 4.0 * k, 25.0, 0.8)]
            reads = [None, None]
            if k == 0:
                reads = [TagRead(3, 3, np.zeros((4, 2)), 0, 40.0, 1.0), TagRead(9, 9, np.zeros((4, 2)), 0, 40.0, 1.0)]
            outs.append(_tracked(tracker.update(circles, reads, motion=motion), circles, who, k))
        return outs

    plain = sequence(None)
    for k, out in enumerate(plain):
        _require([t.node for t in out] == [3, 9], who,
                 f"frame {k}: node ids {[t.node for t in out]}, expected [3, 9]: carry a track's node id through "
                 f"frames where its tag is not read")
    last = [t.track for t in plain[-1]]
    _require(None not in last and last[0] != last[1], who,
             f"after {frames} frames the two discs need distinct track ids, got {last}")
    for k, out in enumerate(plain):
        _require(all(t.track in (None, want) for t, want in zip(out, last)), who,
                 f"frame {k}: track ids {[t.track for t in out]} differ from the final {last} on slowly moving "
                 f"discs: once given, a track id stays with its disc")
    ident = sequence(np.eye(3))
    key = [[(t.node, t.track) for t in out] for out in plain]
    _require([[(t.node, t.track) for t in out] for out in ident] == key, who,
             "an identity motion homography changed the output: motion=np.eye(3) must mean no camera motion")
    _require([[(t.node, t.track) for t in out] for out in sequence(None)] == key, who,
             "reset() then the same frames gave another output: reset() must forget every track")
