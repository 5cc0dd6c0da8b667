"""The rig file ``decentral.rig/1`` (TOML): what ``decentral build-log`` turns into a ``decentral.log/1``.

A rig file describes the robots and where their recorded data is; paths are relative to the rig
file's folder. Documented in full, with an example, in ``docs/rig.md``::

    format = "decentral.rig/1"
    node_radius = 0.06
    tolerance = 0.02        # s: a frame gets odometry only if a sample lies this close (default 0.05)
    clock = "A0/cam0"       # the camera whose frames are the log's steps (default: the first camera)

    [assemblies.A0]
    nodes = { 0 = [0.0, 0.0, 0.0], 1 = [0.2, 0.0, 0.0] }    # or: layout = "A0_layout.json"
    odometry = { file = "A0.tum" }                          # or { file = "A0.csv" }, { bag = "run", topic = "/a0/odom" }

    [assemblies.A0.cameras.cam0]
    K = [[760, 0, 512], [0, 760, 384], [0, 0, 1]]
    strut_in_root = { R = [[1, 0, 0], [0, 1, 0], [0, 0, 1]], p = [0.09, 0.02, 0.0] }
    cam_in_strut = { R = [[0, 0, 1], [-1, 0, 0], [0, -1, 0]], p = [0.05, 0.0, 0.04] }
    detections = "A0_cam0.json"      # decentral.detections/1 whose frames carry "t" (or give times = "FILE")
    # frames = "img/*.png" or video = "cam0.mp4", with times = "FILE" or rate = HZ (and start = T0): perceived
    # bag = "run", image_topic = "/a0/cam0/image_raw", info_topic = "/a0/cam0/camera_info": perceived

    [perception]             # optional: options of the perception front end for frames, videos and bag images
    family = "tag36h11"
    min_radius = 8.0
    max_radius = 160.0
"""

from __future__ import annotations

import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from decentral.errors import InputError
from decentral.observations import Pose
from sims.io.kinds import require_kind
from sims.io.log_json import parse_camera_matrix, parse_pose
from sims.io.robot_files import Layout, parse_nodes, read_layout
from sims.io.text import read_text
from sims.io.validate import require_mapping, require_number, require_positive

__all__ = ["RIG_FORMAT", "OdometrySource", "FrameSource", "RigCamera", "RigAssembly", "Rig", "read_rig", "parse_rig"]

RIG_FORMAT = "decentral.rig/1"


@dataclass(frozen=True)
class OdometrySource:
    """An odometry trajectory file (TUM or CSV), or a ``nav_msgs/Odometry`` topic of a bag."""

    path: Path
    topic: str | None = None


@dataclass(frozen=True)
class FrameSource:
    """Where a camera's frames come from.

    ``kind`` is ``"detections"`` (a ``decentral.detections/1`` file: ``path``), ``"frames"`` (image
    files: ``paths``), ``"video"`` (``path``) or ``"bag"`` (``path``, ``image_topic``, ``info_topic``).
    Frame times: the detections' ``t``, the bag's header stamps, else ``times`` (a times file) or
    ``start + k / rate``.
    """

    kind: str
    path: Path | None = None
    paths: tuple[Path, ...] = ()
    times: Path | None = None
    rate: float | None = None
    start: float = 0.0
    image_topic: str | None = None
    info_topic: str | None = None


@dataclass(frozen=True)
class RigCamera:
    """A camera of the rig: intrinsics (``None``: from the bag's CameraInfo), mounting, frame source."""

    assembly: str
    name: str
    K: np.ndarray | None
    strut_in_root: Pose
    cam_in_strut: Pose
    source: FrameSource

    @property
    def key(self) -> str:
        return f"{self.assembly}/{self.name}"


@dataclass(frozen=True)
class RigAssembly:
    """An assembly: its node layout over time, its odometry source (or none), its cameras."""

    name: str
    layout: Layout
    odometry: OdometrySource | None
    cameras: tuple[RigCamera, ...]


@dataclass(frozen=True)
class Rig:
    """A whole rig file."""

    source: str
    node_radius: float
    tolerance: float
    clock: str
    assemblies: tuple[RigAssembly, ...]
    perception: dict = field(default_factory=dict)

    @property
    def cameras(self) -> dict[str, RigCamera]:
        return {cam.key: cam for a in self.assemblies for cam in a.cameras}


_TOP_KEYS = {"format", "node_radius", "tolerance", "clock", "assemblies", "perception"}
_ASSEMBLY_KEYS = {"nodes", "layout", "odometry", "cameras"}
_CAMERA_KEYS = {"K", "strut_in_root", "cam_in_strut", "detections", "frames", "video", "bag", "image_topic",
                "info_topic", "times", "rate", "start"}
_PERCEPTION_KEYS = {"family": str, "min_radius": float, "max_radius": float}


def _no_unknown(table: dict, known: set, field: str) -> None:
    for key in table:
        if key not in known:
            raise InputError(f"unknown key (known: {', '.join(sorted(known))})", field=f"{field}.{key}" if field else key)


def _string(value: Any, field: str) -> str:
    if not isinstance(value, str) or not value:
        raise InputError("expected a non-empty string", field=field)
    return value


def _odometry(value: Any, field: str, root: Path) -> OdometrySource:
    value = require_mapping(value, field)
    _no_unknown(value, {"file", "bag", "topic"}, field)
    if ("file" in value) == ("bag" in value):
        raise InputError("give either file = PATH or bag = PATH with topic = NAME", field=field)
    if "file" in value:
        return OdometrySource(root / _string(value["file"], f"{field}.file"))
    if "topic" not in value:
        raise InputError("missing (the nav_msgs/Odometry topic)", field=f"{field}.topic")
    return OdometrySource(root / _string(value["bag"], f"{field}.bag"), _string(value["topic"], f"{field}.topic"))


def _frame_source(cam: dict, field: str, root: Path) -> FrameSource:
    kinds = [k for k in ("detections", "frames", "video", "bag") if k in cam]
    if len(kinds) != 1:
        raise InputError("give exactly one of detections, frames, video, bag", field=field)
    kind = kinds[0]
    times = root / _string(cam["times"], f"{field}.times") if "times" in cam else None
    rate = require_positive(cam["rate"], f"{field}.rate") if "rate" in cam else None
    start = require_number(cam.get("start", 0.0), f"{field}.start")
    if kind == "bag":
        if "image_topic" not in cam:
            raise InputError("missing (the sensor_msgs/Image or CompressedImage topic)", field=f"{field}.image_topic")
        return FrameSource("bag", root / _string(cam["bag"], f"{field}.bag"), image_topic=_string(cam["image_topic"], f"{field}.image_topic"),
                           info_topic=_string(cam["info_topic"], f"{field}.info_topic") if "info_topic" in cam else None)
    for key in ("image_topic", "info_topic"):
        if key in cam:
            raise InputError("only with bag = PATH", field=f"{field}.{key}")
    if kind == "frames":
        pattern = _string(cam["frames"], f"{field}.frames")
        paths = tuple(sorted(root.glob(pattern))) if not Path(pattern).is_absolute() else tuple(
            sorted(Path(pattern).parent.glob(Path(pattern).name)))
        if not paths:
            raise InputError(f"no file matches {pattern!r}", field=f"{field}.frames")
        if times is None and rate is None:
            raise InputError("frames need their times: times = FILE or rate = HZ", field=f"{field}.times")
        return FrameSource("frames", paths=paths, times=times, rate=rate, start=start)
    path = root / _string(cam[kind], f"{field}.{kind}")
    if kind == "video" and times is None and rate is None:
        raise InputError("a video needs its frame times: times = FILE or rate = HZ", field=f"{field}.times")
    return FrameSource(kind, path, times=times, rate=rate, start=start)


def _camera(assembly: str, name: str, cam: Any, field: str, root: Path) -> RigCamera:
    cam = require_mapping(cam, field)
    _no_unknown(cam, _CAMERA_KEYS, field)
    for key in ("strut_in_root", "cam_in_strut"):
        if key not in cam:
            raise InputError("missing", field=f"{field}.{key}")
    source = _frame_source(cam, field, root)
    if "K" not in cam and source.info_topic is None:
        raise InputError("missing (or give info_topic with a bag)", field=f"{field}.K")
    K = parse_camera_matrix(cam["K"], f"{field}.K") if "K" in cam else None
    return RigCamera(assembly, name, K, parse_pose(cam["strut_in_root"], f"{field}.strut_in_root"),
                     parse_pose(cam["cam_in_strut"], f"{field}.cam_in_strut"), source)


def _assembly(name: str, body: Any, root: Path) -> RigAssembly:
    field = f"assemblies.{name}"
    body = require_mapping(body, field)
    _no_unknown(body, _ASSEMBLY_KEYS, field)
    if ("nodes" in body) == ("layout" in body):
        raise InputError("give either nodes = {ID = [x, y, z], ...} or layout = FILE", field=field)
    if "nodes" in body:
        layout = Layout(np.zeros(1), (parse_nodes(body["nodes"], f"{field}.nodes"),))
    else:
        layout = read_layout(root / _string(body["layout"], f"{field}.layout"))
    odometry = _odometry(body["odometry"], f"{field}.odometry", root) if "odometry" in body else None
    cams = require_mapping(body.get("cameras", {}), f"{field}.cameras")
    cameras = tuple(_camera(name, cam_name, cam, f"{field}.cameras.{cam_name}", root) for cam_name, cam in cams.items())
    for mounts in layout.mounts:
        for cam_name in mounts:
            if cam_name not in cams:
                raise InputError(f"the layout file mounts camera {cam_name!r}, which the assembly does not have",
                                 field=f"{field}.layout")
    return RigAssembly(name, layout, odometry, cameras)


def _check_unique_nodes(assemblies: tuple[RigAssembly, ...]) -> None:
    """Refuse a node id held by two assemblies at once (at any time a layout changes).

    A module may leave one assembly and later join another; what the log forbids is one id in two
    configurations of the same step. The error names the file (rig or layout file) and field where
    the second holder lists the node.
    """
    changes = sorted({float(t) for a in assemblies for t in a.layout.times})
    for t in changes:
        owner: dict[int, str] = {}
        for a in assemblies:
            index = a.layout.index(t)
            for node in a.layout.nodes[index]:
                if node in owner:
                    raise InputError(f"node id {node} also belongs to {owner[node]}"
                                     + (f" at t={t:g}" if a.layout.source or len(changes) > 1 else ""),
                                     source=a.layout.source or None,
                                     field=a.layout.field(index, node, f"assemblies.{a.name}.nodes"))
                owner[node] = a.name


def parse_rig(doc: Any, root: str | os.PathLike = ".", source: str = "") -> Rig:
    """Validate a decoded rig document (paths relative to ``root``)."""
    doc = require_mapping(doc, "(top level)")
    _no_unknown(doc, _TOP_KEYS, "")
    if doc.get("format") != RIG_FORMAT:
        raise InputError(f"expected {RIG_FORMAT!r}, got {doc.get('format')!r}", field="format")
    radius = require_positive(doc.get("node_radius"), "node_radius")
    tolerance = require_positive(doc.get("tolerance", 0.05), "tolerance")
    raw = require_mapping(doc.get("assemblies"), "assemblies")
    if not raw:
        raise InputError("no assemblies", field="assemblies")
    assemblies = tuple(_assembly(name, body, Path(root)) for name, body in raw.items())
    _check_unique_nodes(assemblies)
    cameras = [cam.key for a in assemblies for cam in a.cameras]
    if not cameras:
        raise InputError("no camera: at least one assembly needs cameras", field="assemblies")
    clock = _string(doc.get("clock", cameras[0]), "clock")
    if clock not in cameras:
        raise InputError(f"not a camera of the rig ({', '.join(cameras)})", field="clock")
    perception = require_mapping(doc.get("perception", {}), "perception")
    _no_unknown(perception, set(_PERCEPTION_KEYS), "perception")
    options = {}
    for key, kind in _PERCEPTION_KEYS.items():
        if key in perception:
            options[key] = _string(perception[key], f"perception.{key}") if kind is str else require_positive(
                perception[key], f"perception.{key}")
    return Rig(source, radius, tolerance, clock, assemblies, options)


def read_rig(path: str | os.PathLike) -> Rig:
    """Read and validate a rig file; errors name the file and the field."""
    require_kind(path, RIG_FORMAT)
    text = read_text(path)
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise InputError(f"not valid TOML ({err})", source=str(path)) from None
    except RecursionError:  # arrays or tables nested past the parser's recursion limit
        raise InputError("not valid TOML (nested too deeply)", source=str(path)) from None
    try:
        return parse_rig(doc, Path(path).parent, str(path))
    except InputError as err:
        raise err.located(str(path)) from None
