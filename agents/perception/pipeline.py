"""The perception front end of one camera: detect circles, read tags, track (Liu et al. 2024 §III).

:class:`Perception` chains the three swappable stages (any objects meeting the protocols of
:mod:`agents.perception.types`) and the camera-motion source; :func:`perceive_frames` runs it over a
sequence of images and returns one :class:`FrameResult` per image.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable, Iterable, Sequence

import numpy as np

from agents.perception.apriltag3 import make_identifier
from agents.perception.detectors import make_detector
from agents.perception.motion import FlowRegistration
from agents.perception.read_owner import PrintScale, unambiguous_reads
from agents.perception.tracking import CircleTracker, TrackerConfig
from agents.perception.types import Circle, CircleDetector, Identifier, TrackedCircle, Tracker

__all__ = ["FrameResult", "Perception", "perceive_frames"]

MotionSource = Callable[[np.ndarray, Sequence[Circle]], "np.ndarray | None"]


@dataclass(frozen=True)
class FrameResult:
    """What perception made of one frame: its detections and the CPU time each stage took (s)."""

    source: str
    detections: tuple[TrackedCircle, ...]
    seconds: dict[str, float]


class Perception:
    """Detector + identifier + (optional) tracker + (optional) camera-motion source.

    Parameters
    ----------
    detector : CircleDetector or str, optional
        A detector, or its name for :func:`~agents.perception.detectors.make_detector`
        (:data:`~agents.perception.detectors.DETECTORS`); default
        :data:`~agents.perception.detectors.DEFAULT_DETECTOR`.
    identifier : Identifier, optional
        Default :func:`~agents.perception.apriltag3.make_identifier` (tag36h11): the AprilTag 3
        library inside each circle, OpenCV's reader where it reads nothing. Its reads pass
        :func:`~agents.perception.read_owner.unambiguous_reads`: a read that a nearer or overlapping
        circle could own is dropped; then :class:`~agents.perception.read_owner.PrintScale`: a read
        whose print is far too small or large for its circle is dropped (see ``print_scale``).
    tracker : Tracker or None
        Default :class:`~agents.perception.tracking.CircleTracker` (``trust_uncontested`` when the
        detector's ``finds_neighbours`` is True); ``track=False`` disables it
        (then a detection's node id is its tag read's, and its track is None).
    motion : callable or None
        ``motion(image, circles) -> H (3, 3) or None``, the camera motion since the previous frame
        when :meth:`process` is not given one; default :class:`FlowRegistration` when tracking.
    print_scale : PrintScale, None or "auto"
        Rule 4 of the tag reads (:class:`~agents.perception.read_owner.PrintScale`); ``"auto"`` (the
        default): on for a detector whose circles are the spheres' outlines (its ``outlines_spheres``
        is True: the learned one), off for the others (hough's circle is sometimes the print itself,
        and the rule then dropped right reads: on held-out scene 1005 its wrong ids rose 20.7 -> 35.3 %).
    """

    def __init__(
        self,
        detector: CircleDetector | str | None = None,
        identifier: Identifier | None = None,
        tracker: Tracker | None = None,
        *,
        track: bool = True,
        motion: MotionSource | None | str = "flow",
        print_scale: PrintScale | None | str = "auto",
    ):
        self.detector = make_detector(detector) if isinstance(detector, str) else detector or make_detector()
        self.identifier = identifier or make_identifier()
        # a detector that finds nearly every node lets the tracker keep ids through uncontested jumps
        trust = bool(getattr(self.detector, "finds_neighbours", False))
        self.tracker = (tracker or CircleTracker(TrackerConfig(trust_uncontested=trust))) if track else None
        if motion == "flow":
            motion = FlowRegistration() if track else None
        self.motion = motion
        if print_scale == "auto":
            print_scale = PrintScale() if getattr(self.detector, "outlines_spheres", False) else None
        self.print_scale = print_scale

    def reset(self) -> None:
        """Start a new sequence."""
        if self.print_scale is not None:
            self.print_scale.reset()
        if self.tracker is not None:
            self.tracker.reset()
        reset = getattr(self.motion, "reset", None)
        if reset is not None:
            reset()

    def _sized(self, circles, reads):
        """``reads`` after rule 4 (:attr:`print_scale`), where it is on."""
        return reads if self.print_scale is None else self.print_scale.filter(circles, reads)

    def process(self, image: np.ndarray, *, motion: np.ndarray | None = None) -> tuple[list[TrackedCircle], dict[str, float]]:
        """Run one frame; ``motion`` (3, 3) overrides the motion source (e.g. from odometry).

        Returns the tracked detections and the CPU seconds of each stage (process time: on a shared
        machine wall time measures the other processes too).
        """
        t0 = time.process_time()
        circles = self.detector.detect(image)
        t1 = time.process_time()
        if self.tracker is None:
            reads = self._sized(circles, unambiguous_reads(circles, self.identifier.identify(image, circles)))
            t2 = time.process_time()
            out = [TrackedCircle(c, r, r.node if r is not None else None, None) for c, r in zip(circles, reads)]
            return out, {"detect": t1 - t0, "identify": t2 - t1}
        if motion is None and self.motion is not None:
            motion = self.motion(image, circles)
        t2 = time.process_time()
        # circles whose track is beyond doubt are not read in every frame (the tracker says which)
        settled = getattr(self.tracker, "settled", None)
        skip = settled(circles, motion=motion) if settled is not None else np.zeros(len(circles), dtype=bool)
        todo = [c for c, s in zip(circles, skip) if not s]
        # a reader with a slower fallback (AprilTag3Identifier) spares it the circles whose tracked id
        # no read can change (the tracker's carried(); a read there could only add a vote)
        carried = getattr(self.tracker, "carried", None)
        if todo and carried is not None and getattr(self.identifier, "fallback", None) is not None:
            sure = carried(circles, motion=motion)
            got = iter(self.identifier.identify(image, todo, fallback=[not x for x, s in zip(sure, skip) if not s]))
        else:
            got = iter(self.identifier.identify(image, todo) if todo else [])
        # a read that another circle of the frame could own is dropped (agents.perception.read_owner)
        reads = self._sized(circles, unambiguous_reads(circles, [None if s else next(got) for s in skip]))
        t3 = time.process_time()
        out = self.tracker.update(circles, reads, motion=motion)
        t4 = time.process_time()
        return out, {"detect": t1 - t0, "identify": t3 - t2, "motion": t2 - t1, "track": t4 - t3}


def perceive_frames(
    frames: Iterable[tuple[str, np.ndarray]],
    perception: Perception | None = None,
    *,
    motions: Sequence[np.ndarray | None] | None = None,
) -> list[FrameResult]:
    """Run perception over ``(source name, image)`` pairs in time order.

    ``motions``, if given, holds one camera-motion homography (or None) per frame and replaces the
    perception's own motion source (e.g. homographies from the observer's odometry).
    """
    perception = perception or Perception()
    perception.reset()
    results = []
    for k, (name, image) in enumerate(frames):
        given = motions[k] if motions is not None and k < len(motions) else None
        dets, secs = perception.process(image, motion=given)
        results.append(FrameResult(name, tuple(dets), secs))
    return results
