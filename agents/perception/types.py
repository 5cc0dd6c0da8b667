"""Data types and the swappable stage interfaces of the perception front end (Liu et al. 2024 §III).

An image goes through three stages, each behind a :class:`typing.Protocol` so a user can swap it:
a :class:`CircleDetector` (image -> bounding circles, §III-A), an :class:`Identifier` (AprilTag reads
inside each circle, §III-B) and a :class:`Tracker` (circles across frames, ids that survive tag
drop-outs, §III-C). Images are numpy arrays, (H, W) grey or (H, W, 3) BGR, uint8; pixel coordinates
follow OpenCV: ``u`` to the right, ``v`` down, the centre of the top-left pixel at (0, 0).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, Sequence, runtime_checkable

import numpy as np

__all__ = [
    "Circle",
    "TagRead",
    "TrackedCircle",
    "CircleDetector",
    "Identifier",
    "Tracker",
]


@dataclass(frozen=True)
class Circle:
    """A bounding circle of one spherical node in an image (Liu et al. 2024 §III-A, y = [u, v, r]).

    Attributes
    ----------
    u, v : float
        Centre in pixels.
    r : float
        Radius in pixels (> 0).
    score : float
        Detector confidence in [0, 1]; for the classical detector the fraction of the rim that
        supports the fitted circle.
    """

    u: float
    v: float
    r: float
    score: float


@dataclass(frozen=True)
class TagRead:
    """One AprilTag read inside a circle (Liu et al. 2024 §III-B).

    Attributes
    ----------
    tag : int
        Tag id in its family.
    node : int or None
        Node id the tag names (through the identifier's tag table); None if the table does not know it.
    corners : ndarray, shape (4, 2)
        Tag corners in image pixels, in the family's canonical order (top-left, top-right,
        bottom-right, bottom-left of the upright tag).
    hamming : int
        Bits of the read code that differ from the dictionary code of ``tag``.
    margin : float
        Decision margin: how far, in grey levels, the tag's cells sit from the black/white threshold
        (the smaller of the mean distances of the white and of the black cells).
    confidence : float
        OpenCV's own marker confidence in [0, 1].
    """

    tag: int
    node: int | None
    corners: np.ndarray
    hamming: int
    margin: float
    confidence: float


@dataclass(frozen=True)
class TrackedCircle:
    """A detection after tracking: its circle, its tag read (if any), its track and node ids.

    ``node`` is None where neither the tag nor the track names the node; ``track`` is None when the
    detection was not associated with a track (tracking off, or a low-score detection left over).
    """

    circle: Circle
    read: TagRead | None
    node: int | None
    track: int | None


@runtime_checkable
class CircleDetector(Protocol):
    """Image -> bounding circles of the spherical nodes in it."""

    def detect(self, image: np.ndarray) -> list[Circle]:
        """Return the circles found in ``image`` ((H, W) or (H, W, 3), uint8), best first."""
        ...


@runtime_checkable
class Identifier(Protocol):
    """Reads the tag inside each circle."""

    def identify(self, image: np.ndarray, circles: Sequence[Circle]) -> list[TagRead | None]:
        """Return one entry per circle: its accepted tag read, or None."""
        ...


@runtime_checkable
class Tracker(Protocol):
    """Associates the circles of successive frames and carries node ids through tag drop-outs."""

    def update(
        self,
        circles: Sequence[Circle],
        reads: Sequence[TagRead | None],
        *,
        motion: np.ndarray | None = None,
    ) -> list[TrackedCircle]:
        """Advance one frame.

        Parameters
        ----------
        circles, reads : sequences of equal length
            This frame's detections and their tag reads.
        motion : ndarray, shape (3, 3), optional
            Camera-motion homography mapping pixels of the previous frame to this frame (from the
            observer's odometry or image registration); None: no compensation.

        Returns
        -------
        list of TrackedCircle
            One per input circle, in the input order.
        """
        ...

    def reset(self) -> None:
        """Forget every track (a new sequence starts)."""
        ...
