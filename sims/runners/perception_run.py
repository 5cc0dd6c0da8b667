"""Perception of one camera's frames, alone or guided by an observation log (camera model and configurations).

:func:`perceive_paths` runs the front end over image files or one video (``decentral perceive``);
:func:`perceive_with_log`, shared by ``perceive --log-template``, ``build-log`` and the experiments,
runs it frame k = step k of a log: with the camera intrinsics and mounting, circles become eq. (1)
circles, tags are read through the sphere model against the tags of the nodes configured at each
step, and (optionally) the observer's odometry compensates its own rotation in the tracker.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable, Iterable, Iterator, Sequence

import numpy as np

from agents.perception.detectors import DEFAULT_DETECTOR
from decentral.errors import InputError
from decentral.observations import ObservationLog

__all__ = ["PerceivedCamera", "perceive_paths", "perceive_with_log", "to_records"]

#: accepted --min-radius / --max-radius, pixels
RADIUS_RANGE = (1.0, 1e5)


@dataclass(frozen=True)
class PerceivedCamera:
    """One camera's perceived frames (:class:`sims.io.detections_json.DetectionFrame`) and CPU seconds per frame."""

    frames: tuple
    seconds: tuple[float, ...]


def perceive_with_log(
    images: Iterable[tuple[str, np.ndarray]],
    log: ObservationLog,
    camera: str,
    *,
    family: str = "tag36h11",
    tag_table: dict[int, int] | None = None,
    track: bool = True,
    motion: str = "auto",
    min_radius: float = 8.0,
    max_radius: float = 160.0,
    layout=None,
    detector: str = DEFAULT_DETECTOR,
) -> PerceivedCamera:
    """Run perception over ``(name, image)`` pairs, frame k being step k of ``log`` seen by ``camera``.

    ``motion`` is ``"flow"`` (image registration), ``"odometry"`` (the observer's yaw odometry),
    ``"auto"`` (odometry when the log has any for the camera's assembly, else flow: odometry is
    free, registration costs about 2 ms per frame) or ``"none"``; ``layout`` the
    :class:`~agents.perception.sphere_tags.StickerLayout` (default: the renderer's); ``detector`` the
    circle detector's name (:data:`agents.perception.detectors.DETECTORS`, default
    :data:`~agents.perception.detectors.DEFAULT_DETECTOR`;
    :func:`agents.perception.make_detector`).
    """
    from agents.perception import Perception, make_detector
    from agents.perception.motion import odometry_homography
    from agents.perception.sphere_tags import SphereTagConfig, SphereTagIdentifier, StickerLayout

    if camera not in log.cameras:
        raise InputError(f"camera {camera!r} is not declared in the log", field="--camera")
    cam = log.cameras[camera]
    if motion == "auto":
        motion = "odometry" if any(cam.assembly in step.odometry for step in log.steps[1:]) else "flow"
    circles = make_detector(detector, min_radius, max_radius)
    cfg = SphereTagConfig(layout=layout or StickerLayout.around(), family=family, tag_table=tag_table)
    identifier = SphereTagIdentifier(cam.K, log.node_radius, cfg)
    perception = Perception(circles, identifier, track=track, motion="flow" if motion == "flow" else None)
    inverse = None if tag_table is None else {n: t for t, n in tag_table.items()}
    results, seconds = [], []
    from agents.perception.pipeline import FrameResult

    for k, (name, image) in enumerate(images):
        if k >= len(log.steps):
            raise InputError(f"more frames than the {len(log.steps)} steps of the log", field="FRAME")
        start = time.process_time()
        step = log.steps[k]
        nodes = [n for cfg_nodes in step.config.values() for n in cfg_nodes]
        tags = nodes if inverse is None else [inverse[n] for n in nodes if n in inverse]
        identifier.set_view(log.camera_pose(camera, step).R, tags)
        given = None
        if motion == "odometry" and k > 0:
            odo = step.odometry.get(cam.assembly)
            if odo is not None:
                given = odometry_homography(cam.K, log.camera_pose(camera, step).R, odo.dtheta)
        dets, secs = perception.process(image, motion=given)
        results.append(FrameResult(name, tuple(dets), secs))
        seconds.append(time.process_time() - start)
    return PerceivedCamera(tuple(to_records(results, K=cam.K)), tuple(seconds))


def to_records(results, *, K: np.ndarray | None = None):
    """Turn :class:`agents.perception.FrameResult` s into :class:`sims.io.detections_json.DetectionFrame` s.

    With intrinsics ``K``, each circle becomes its eq. (1) circle (:func:`agents.perception.sphere.eq1_circle`).
    """
    from agents.perception.sphere import eq1_circle
    from sims.io.detections_json import DetectionFrame, DetectionRecord, TagRecord

    frames = []
    for res in results:
        dets = []
        for d in res.detections:
            c = eq1_circle(d.circle, K) if K is not None else d.circle
            tag = None
            if d.read is not None:
                tag = TagRecord(d.read.tag, d.read.hamming, d.read.margin, np.asarray(d.read.corners))
            dets.append(DetectionRecord(c.u, c.v, c.r, c.score, d.node, d.track, tag))
        frames.append(DetectionFrame(res.source, tuple(dets)))
    return frames


def _frames(paths: Sequence[str], max_pixels: int | None, progress: Callable[[Iterator], Iterator] | None):
    """The frames of ``paths`` (:func:`~agents.perception.frame_reader.iter_frames`), wrapped by ``progress``."""
    from agents.perception.frame_reader import iter_frames

    frames = iter_frames(list(paths), max_pixels)
    return frames if progress is None else progress(frames)


def perceive_paths(
    paths: Sequence[str],
    *,
    family: str = "tag36h11",
    track: bool = True,
    tag_table: dict[int, int] | None = None,
    min_radius: float = 8.0,
    max_radius: float = 160.0,
    motion: str = "auto",
    detector: str = DEFAULT_DETECTOR,
    log=None,
    camera: str | None = None,
    max_pixels: int | None = None,
    progress: Callable[[Iterator], Iterator] | None = None,
):
    """Run perception over image files or one video; return the :class:`DetectionFrame` list.

    ``log`` (an :class:`~decentral.observations.ObservationLog`) and ``camera`` supply the camera
    model (eq. (1) circles) and, with ``motion="odometry"`` (or ``"auto"``, the default, when the log
    has odometry for the camera's assembly), the observer's rotation per step; without a log,
    ``"auto"`` is image registration. Frames over ``max_pixels`` pixels are refused before decoding.
    ``progress``, if given, wraps the iterator of ``(name, image)`` frames (a progress bar, say).
    """
    from agents.perception import Perception, make_detector
    from agents.perception.apriltag3 import make_identifier
    from agents.perception.pipeline import perceive_frames
    from sims.io.validate import require_range

    require_range(min_radius, "--min-radius", *RADIUS_RANGE)
    require_range(max_radius, "--max-radius", *RADIUS_RANGE)
    if max_radius <= min_radius:
        raise InputError("need --min-radius < --max-radius", field="--min-radius")
    circles = make_detector(detector, min_radius, max_radius)
    try:
        identifier = make_identifier(family, tag_table)
    except ValueError as err:
        raise InputError(str(err), field="--family") from None
    if log is None:
        if motion == "odometry":
            raise InputError("--motion odometry needs --log-template and --camera", field="--motion")
        perception = Perception(circles, identifier, track=track, motion="flow" if motion in ("flow", "auto") else None)
        return to_records(perceive_frames(_frames(paths, max_pixels, progress), perception))
    return list(perceive_with_log(_frames(paths, max_pixels, progress), log, camera, family=family, tag_table=tag_table,
                                  track=track, motion=motion, min_radius=min_radius, max_radius=max_radius,
                                  detector=detector).frames)
