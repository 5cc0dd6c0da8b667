"""``decentral perceive``: camera frames -> node detections (``decentral.detections/1``), optionally a log.

Images (in time order) or one video go through the perception front end of :mod:`agents.perception`:
bounding circles, AprilTag ids inside them, tracking so a node keeps its id through tag drop-outs.
With ``--log-template LOG.json --camera A0/cam0 --log-out OUT.json`` the same run also writes a
``decentral.log/1``: the template's steps (configurations, odometry) with that camera's detections
replaced by the perceived, identified ones (frame k = step k), its camera model used to turn each
circle into the circle of seed 000 eq. (1) and, with ``--motion odometry``, to compensate the
observer's own rotation in the tracker.
"""

from __future__ import annotations

import argparse
from typing import Sequence

import numpy as np

from decentral.errors import InputError

__all__ = ["HELP", "add_arguments", "run", "perceive_paths", "to_records"]

HELP = "find, identify and track the spherical nodes in camera frames (writes decentral.detections/1)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("frames", nargs="+", metavar="FRAME", help="image files in time order, or one video file")
    parser.add_argument("-o", "--output", required=True, metavar="DETS.json", help="detections output (decentral.detections/1)")
    parser.add_argument("--family", default="tag36h11", help="AprilTag family (default tag36h11)")
    parser.add_argument("--no-track", action="store_true", help="no tracking: ids come from tag reads only")
    parser.add_argument("--tag-table", metavar="TABLE.json", help='JSON object tag id -> node id (default: node id = tag id)')
    parser.add_argument("--min-radius", type=float, default=8.0, help="smallest node radius in pixels (default 8)")
    parser.add_argument("--max-radius", type=float, default=160.0, help="largest node radius in pixels (default 160)")
    parser.add_argument("--detector", choices=("hough", "rim"), default="hough",
                        help="circle detector: hough (default, fast) or rim (finds the rim where hough fits the tag "
                        "on large low-contrast or partly hidden spheres; about 3x slower)")
    parser.add_argument("--motion", choices=("auto", "flow", "odometry", "none"), default="auto",
                        help="camera-motion compensation for tracking: auto (default: the observer's "
                             "odometry when --log-template has it, else image registration), flow (image "
                             "registration), odometry (from --log-template), or none")
    parser.add_argument("--log-template", metavar="LOG.json", help="a decentral.log/1 whose detections to fill")
    parser.add_argument("--camera", metavar="ASSEMBLY/CAMERA", help="the camera of the frames in --log-template")
    parser.add_argument("--log-out", metavar="LOG_OUT.json", help="where to write the filled decentral.log/1")
    parser.add_argument("--log-min-score", type=float, default=0.5,
                        help="detections with a lower rim score stay out of --log-out (default 0.5); so do "
                             "circles not wholly inside the image")


def _tag_table(path: str | None) -> dict[int, int] | None:
    if path is None:
        return None
    from sims.io.log_json import load_json
    from sims.io.validate import require_int, require_mapping

    doc = require_mapping(load_json(path), "(top level)")
    try:
        return {require_int(k, f"[{k!r}]"): require_int(v, f"[{k!r}]") for k, v in doc.items()}
    except InputError as err:
        raise err.located(path) from None


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


def perceive_paths(
    paths: Sequence[str],
    *,
    family: str = "tag36h11",
    track: bool = True,
    tag_table: dict[int, int] | None = None,
    min_radius: float = 8.0,
    max_radius: float = 160.0,
    motion: str = "auto",
    detector: str = "hough",
    log=None,
    camera: str | None = None,
):
    """Run perception over image files or one video; return the :class:`DetectionFrame` list.

    ``log`` (an :class:`~decentral.observations.ObservationLog`) and ``camera`` supply the camera
    model (eq. (1) circles) and, with ``motion="odometry"`` (or ``"auto"``, the default, when the log
    has odometry for the camera's assembly), the observer's rotation per step; without a log,
    ``"auto"`` is image registration.
    """
    from agents.perception import AprilTagConfig, AprilTagIdentifier, Perception, make_detector
    from agents.perception.frames import iter_frames
    from agents.perception.pipeline import perceive_frames

    if max_radius <= min_radius or min_radius <= 0:
        raise InputError("need 0 < --min-radius < --max-radius", field="--min-radius")
    circles = make_detector(detector, min_radius, max_radius)
    try:
        identifier = AprilTagIdentifier(AprilTagConfig(family=family, tag_table=tag_table))
    except ValueError as err:
        raise InputError(str(err), field="--family") from None
    if log is None:
        if motion == "odometry":
            raise InputError("--motion odometry needs --log-template and --camera", field="--motion")
        perception = Perception(circles, identifier, track=track, motion="flow" if motion in ("flow", "auto") else None)
        return to_records(perceive_frames(iter_frames(list(paths)), perception))
    from sims.experiments.perception_run import perceive_with_log

    return list(perceive_with_log(iter_frames(list(paths)), log, camera, family=family, tag_table=tag_table,
                                  track=track, motion=motion, min_radius=min_radius, max_radius=max_radius,
                                  detector=detector).frames)


def run(args: argparse.Namespace) -> int:
    from sims.io.detections_json import assemble_log, write_detections

    given = [args.log_template is not None, args.camera is not None, args.log_out is not None]
    if any(given) and not all(given):
        raise InputError("--log-template, --camera and --log-out go together", field="--log-template")
    from pathlib import Path

    for out in (args.output, args.log_out):  # fail before the work, not half-way through the writes
        if out is not None and not Path(out).resolve().parent.is_dir():
            raise InputError("output folder does not exist", source=str(out))
    log = None
    if args.log_template is not None:
        from sims.io.log_json import read_log

        log = read_log(args.log_template)
        if args.camera not in log.cameras:
            raise InputError(f"camera {args.camera!r} is not declared", source=args.log_template, field="assemblies")
    frames = perceive_paths(
        args.frames,
        family=args.family,
        track=not args.no_track,
        tag_table=_tag_table(args.tag_table),
        min_radius=args.min_radius,
        max_radius=args.max_radius,
        detector=args.detector,
        motion=args.motion,
        log=log,
        camera=args.camera,
    )
    filled = None
    if log is not None:
        try:
            from agents.perception.frames import iter_frames

            _, first = next(iter(iter_frames(args.frames)))
            sizes = {args.camera: (first.shape[1], first.shape[0])}
            filled = assemble_log(log, {args.camera: frames}, min_score=args.log_min_score, image_sizes=sizes)
        except InputError as err:
            raise err.located(args.log_template) from None
    write_detections(args.output, frames)
    if filled is not None:
        from sims.io.log_json import write_log

        write_log(args.log_out, filled)
    return 0
