"""Perception of one camera's frames guided by an observation log (the camera model and the configurations).

Shared by ``decentral perceive --log-template`` and the experiments: with the camera intrinsics and
mounting, circles become eq. (1) circles, tags are read through the sphere model against the tags of
the nodes configured at each step, and (optionally) the observer's odometry compensates its own
rotation in the tracker.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Iterable

import numpy as np

from decentral.errors import InputError
from decentral.observations import ObservationLog

__all__ = ["PerceivedCamera", "perceive_with_log"]


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
    detector: str = "hough",
) -> PerceivedCamera:
    """Run perception over ``(name, image)`` pairs, frame k being step k of ``log`` seen by ``camera``.

    ``motion`` is ``"flow"`` (image registration), ``"odometry"`` (the observer's yaw odometry),
    ``"auto"`` (odometry when the log has any for the camera's assembly, else flow: odometry is
    free, registration costs about 2 ms per frame) or ``"none"``; ``layout`` the
    :class:`~agents.perception.sphere_tags.StickerLayout` (default: the renderer's); ``detector`` the
    circle detector's name (``"hough"``, the default, or ``"rim"``; :func:`agents.perception.make_detector`).
    """
    from agents.perception import Perception, make_detector
    from agents.perception.motion import odometry_homography
    from agents.perception.sphere_tags import SphereTagConfig, SphereTagIdentifier, StickerLayout
    from sims.cli.perceive import to_records

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
