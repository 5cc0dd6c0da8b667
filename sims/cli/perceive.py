"""``decentral perceive``: camera frames -> node detections (``decentral.detections/1``), optionally a log.

Images (in time order) or one video go through the perception front end of :mod:`agents.perception`:
bounding circles, AprilTag ids inside them, tracking so a node keeps its id through tag drop-outs.
With ``--log-template LOG.json --camera A0/cam0 --log-out OUT.json`` the same run also writes a
``decentral.log/1``: the template's steps (configurations, odometry) with that camera's detections
replaced by the perceived, identified ones (frame k = step k), its camera model used to turn each
circle into the circle of Liu et al. 2024 eq. (1) and, with ``--motion odometry``, to compensate the
observer's own rotation in the tracker.
"""

from __future__ import annotations

import argparse
from typing import Sequence

from decentral.errors import InputError
from sims.cli import feedback
from sims.io.limits import current_limits, over_limit

__all__ = ["HELP", "add_arguments", "run"]

HELP = "find, identify and track the spherical nodes in camera frames (writes decentral.detections/1)"

#: the names of agents.perception.apriltag.FAMILIES, listed here so that building the parser of every
#: command does not import OpenCV (a test keeps the two equal)
TAG_FAMILIES = ("tag36h11", "tag25h9", "tag16h5", "tag36h10")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("frames", nargs="+", metavar="FRAME", help="image files in time order, or one video file")
    parser.add_argument("-o", "--output", required=True, metavar="DETS.json", help="detections output (decentral.detections/1)")
    parser.add_argument("--family", default="tag36h11",
                        help=f"AprilTag family: {', '.join(TAG_FAMILIES)} (default: tag36h11)")
    parser.add_argument("--no-track", action="store_true", help="no tracking: ids come from tag reads only")
    parser.add_argument("--tag-table", metavar="TABLE.json", help='JSON object tag id -> node id (default: node id = tag id)')
    parser.add_argument("--min-radius", type=float, default=8.0, help="smallest node radius in pixels (default: 8)")
    parser.add_argument("--max-radius", type=float, default=160.0, help="largest node radius in pixels (default: 160)")
    # (agents.perception.detectors' DETECTORS and DEFAULT_DETECTOR, written out: importing it loads OpenCV)
    parser.add_argument("--detector", choices=("learned", "hough", "rim", "symmetry"), default="learned",
                        help="circle detector: learned (default: the shipped networks, proposals then a second stage "
                             "per circle), hough (no network; good on clean floors, poor elsewhere), rim (finds the rim "
                             "where hough fits the tag; about 3x hough's time) or symmetry (colour-edge symmetry votes; "
                             "about 3x hough's time)")
    parser.add_argument("--motion", choices=("auto", "flow", "odometry", "none"), default="auto",
                        help="camera-motion compensation for tracking: auto (default: the observer's "
                             "odometry when --log-template has it, else image registration), flow (image "
                             "registration), odometry (from --log-template), or none")
    parser.add_argument("--log-template", metavar="LOG.json", help="a decentral.log/1 whose detections to fill")
    parser.add_argument("--camera", metavar="ASSEMBLY/CAMERA", help="the camera of the frames in --log-template")
    parser.add_argument("--log-out", metavar="LOG_OUT.json", help="where to write the filled decentral.log/1")
    parser.add_argument("--log-min-score", type=float, default=None,
                        help="detections with a lower score stay out of --log-out (default: the detector's: 0.5 of "
                             "the rim's support for hough, rim and symmetry, 0 for learned, whose own gates decided); "
                             "so do circles not wholly inside the image")


def _check_image_files(paths: Sequence[str], limits) -> None:
    """Image files are read whole before decoding: refuse one larger than the file-size limit (videos stream)."""
    import os

    from agents.perception.frame_reader import is_video
    from sims.io.kinds import require_kind

    for path in paths:
        require_kind(path, "image", "video")
        if not is_video(path) and os.path.isfile(path) and os.path.getsize(path) > limits.max_file_mb * 1e6:
            raise over_limit("file size", round(os.path.getsize(path) / 1e6, 1), "max_file_mb", limits.max_file_mb,
                             " MB", source=path)


def _tag_table(path: str | None) -> dict[int, int] | None:
    if path is None:
        return None
    from sims.io.kinds import require_kind
    from sims.io.log_json import load_json
    from sims.io.validate import require_int, require_int_key, require_mapping

    require_kind(path, "tag-table", field="--tag-table")
    doc = load_json(path)
    try:
        doc = require_mapping(doc, "(top level)")
        return {require_int_key(k, f"[{k!r}]"): require_int(v, f"[{k!r}]") for k, v in doc.items()}
    except InputError as err:
        raise err.located(path) from None


def _frame_total(paths: Sequence[str]) -> int | None:
    """Number of frames the inputs hold: one per image, a video's frame count (None if unknown)."""
    from agents.perception.frame_reader import is_video, native_stderr_silenced

    if len(paths) == 1 and is_video(paths[0]):
        import cv2

        with native_stderr_silenced():  # FFmpeg prints its own complaints about a damaged file
            cap = cv2.VideoCapture(str(paths[0]))
        try:
            count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        finally:
            cap.release()
        return count if count > 0 else None
    return len(paths)


def run(args: argparse.Namespace) -> int:
    from sims.io.detections_json import assemble_log, write_detections
    from sims.io.validate import require_range

    if args.log_min_score is not None:
        require_range(args.log_min_score, "--log-min-score", -1e6, 1e6)
    limits = current_limits()
    max_pixels = limits.max_pixels
    _check_image_files(args.frames, limits)
    given = [args.log_template is not None, args.camera is not None, args.log_out is not None]
    if any(given) and not all(given):
        raise InputError("--log-template, --camera and --log-out go together", field="--log-template")
    from sims.io.paths import check_output

    inputs = [*args.frames, args.tag_table, args.log_template]  # fail before the work, not half-way through
    check_output(args.output, inputs)
    if args.log_out is not None:
        check_output(args.log_out, [*inputs, args.output], field="--log-out")
    log = None
    if args.log_template is not None:
        from sims.io.log_json import read_log

        log = read_log(args.log_template)
        if args.camera not in log.cameras:
            raise InputError(f"camera {args.camera!r} is not declared", source=args.log_template, field="assemblies")
    from sims.runners.perception_run import perceive_paths

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
        max_pixels=max_pixels,
        progress=lambda frames: feedback.track(frames, "perceive", total=_frame_total(args.frames), unit="frame"),
    )
    filled = None
    if log is not None:
        try:
            from agents.perception.frame_reader import iter_frames

            _, first = next(iter(iter_frames(args.frames, max_pixels)))
            sizes = {args.camera: (first.shape[1], first.shape[0])}
            from agents.perception.detectors import LOG_MIN_SCORE

            min_score = LOG_MIN_SCORE[args.detector] if args.log_min_score is None else args.log_min_score
            filled = assemble_log(log, {args.camera: frames}, min_score=min_score, image_sizes=sizes)
        except InputError as err:
            raise err.located(args.log_template) from None
    write_detections(args.output, frames)
    if filled is not None:
        from sims.io.log_json import write_log

        write_log(args.log_out, filled)
    dets = [d for f in frames for d in f.detections]
    ids = {d.node for d in dets if d.node is not None}
    tracks = {d.track for d in dets if d.track is not None}
    feedback.summary(f"{len(frames)} frames, {len(dets)} detections, {sum(d.node is not None for d in dets)} "
                     f"identified ({len(ids)} node ids, {len(tracks)} tracks) -> {args.output}"
                     + (f", {args.log_out}" if filled is not None else ""))
    return 0
