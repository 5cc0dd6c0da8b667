"""Read and write the contract's JSON files: ``decentral.log/1`` and ``decentral.estimate/1``.

Reading validates every field the contract names and raises :class:`decentral.errors.InputError`
carrying the file and the field path (``steps[3].detections.A0/cam0[1].r``); writing is atomic.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from decentral.errors import InputError
from decentral.observations import (
    Camera,
    Detection,
    Estimate,
    EstimateStep,
    ObservationLog,
    Odometry,
    PlanarPose,
    Pose,
    Step,
    require_estimate,
    require_log,
)
from sims.io.atomic import write_json_atomic
from sims.io.jsonfile import load_json
from sims.io.kinds import require_kind
from sims.io.limits import Limits, current_limits, over_limit
from sims.io.validate import (
    MAX_ANGLE,
    MAX_METRES,
    MAX_PIXELS,
    MAX_SECONDS,
    MIN_METRES,
    MIN_PIXELS,
    require_int,
    require_int_key,
    require_list,
    require_mapping,
    require_matrix,
    require_number,
    require_positive,
    require_rotation,
    require_vector,
)

__all__ = [
    "poses_to_dict",
    "LOG_FORMAT",
    "ESTIMATE_FORMAT",
    "load_json",
    "parse_pose",
    "parse_camera_matrix",
    "read_log",
    "parse_log",
    "log_to_dict",
    "write_log",
    "estimate_to_dict",
    "parse_estimate",
    "read_estimate",
    "write_estimate",
]

LOG_FORMAT = "decentral.log/1"
ESTIMATE_FORMAT = "decentral.estimate/1"


def _check_format(doc: Any, expected: str) -> dict:
    doc = require_mapping(doc, "(top level)")
    if doc.get("format") != expected:
        raise InputError(f"expected {expected!r}, got {doc.get('format')!r}", field="format")
    return doc


# --- decentral.log/1 -------------------------------------------------------------------------


def read_log(path: str | os.PathLike, limits: Limits | None = None) -> ObservationLog:
    """Read and validate a ``decentral.log/1`` file (its assembly count within ``limits``).

    Raises :class:`~decentral.errors.InputError` naming the file and the field on a malformed file.

    Examples
    --------
    >>> import os, tempfile
    >>> from decentral.synthetic import camera, circle_motion, l_config, make_log
    >>> world = {"A": circle_motion(3, (0, 0), 1.0, 0.0, 0.1, 0.0), "B": circle_motion(3, (0, 0), 1.0, 0.8, 0.1, 0.0)}
    >>> log = make_log(world, {"A": l_config([0, 1, 2, 3]), "B": l_config([10, 11, 12, 13])}, [camera("A", yaw=0.5)])
    >>> path = os.path.join(tempfile.mkdtemp(), "log.json")
    >>> write_log(path, log)
    >>> back = read_log(path)
    >>> back.assemblies, len(back.steps)
    (('A', 'B'), 3)
    >>> [len(step.detections["A/cam0"]) for step in back.steps] == [len(s.detections["A/cam0"]) for s in log.steps]
    True
    """
    require_kind(path, LOG_FORMAT)
    limits = limits or current_limits()
    doc = load_json(path, limits)
    count = len(doc["assemblies"]) if isinstance(doc, dict) and isinstance(doc.get("assemblies"), dict) else 0
    if count > limits.max_assemblies:
        raise over_limit("assembly count", count, "max_assemblies", limits.max_assemblies, source=str(path),
                         field="assemblies")
    try:
        return parse_log(doc)
    except InputError as err:
        raise err.located(str(path)) from None


def parse_pose(value: Any, field: str) -> Pose:
    value = require_mapping(value, field)
    for key in ("R", "p"):
        if key not in value:
            raise InputError("missing", field=f"{field}.{key}")
    return Pose(require_rotation(value["R"], f"{field}.R"), require_vector(value["p"], f"{field}.p", 3, MAX_METRES))


def parse_camera_matrix(value: Any, field: str) -> np.ndarray:
    K = require_matrix(value, field, 3, 3, MAX_PIXELS)
    if abs(np.linalg.det(K)) < 1e-9 or K[0, 0] < MIN_PIXELS or K[1, 1] < MIN_PIXELS:
        raise InputError("camera matrix is singular or has non-positive focal lengths", field=field)
    if not np.allclose(K[2], [0.0, 0.0, 1.0]):
        raise InputError("last row of a pinhole K must be [0, 0, 1]", field=field)
    return K


def _parse_cameras(assemblies: dict) -> dict[str, Camera]:
    cameras: dict[str, Camera] = {}
    for name, body in assemblies.items():
        body = require_mapping(body, f"assemblies.{name}")
        cams = require_mapping(body.get("cameras", {}), f"assemblies.{name}.cameras")
        for cam_name, cam in cams.items():
            field = f"assemblies.{name}.cameras.{cam_name}"
            cam = require_mapping(cam, field)
            for key in ("K", "strut_in_root", "cam_in_strut"):
                if key not in cam:
                    raise InputError("missing", field=f"{field}.{key}")
            camera = Camera(
                assembly=name,
                name=cam_name,
                K=parse_camera_matrix(cam["K"], f"{field}.K"),
                strut_in_root=parse_pose(cam["strut_in_root"], f"{field}.strut_in_root"),
                cam_in_strut=parse_pose(cam["cam_in_strut"], f"{field}.cam_in_strut"),
            )
            cameras[camera.key] = camera
    return cameras


def _parse_config(value: Any, field: str, declared: set[str]) -> dict[str, dict[int, np.ndarray]]:
    value = require_mapping(value, field)
    config: dict[str, dict[int, np.ndarray]] = {}
    owner: dict[int, str] = {}
    for name, nodes in value.items():
        if name not in declared:
            raise InputError("assembly is not declared in 'assemblies'", field=f"{field}.{name}")
        nodes = require_mapping(nodes, f"{field}.{name}")
        parsed: dict[int, np.ndarray] = {}
        for key, centre in nodes.items():
            node = require_int_key(key, f"{field}.{name}.{key}")
            if node in owner:
                raise InputError(f"node id {node} also belongs to {owner[node]}", field=f"{field}.{name}.{key}")
            owner[node] = name
            parsed[node] = require_vector(centre, f"{field}.{name}.{key}", 3, MAX_METRES)
        config[name] = parsed
    return config


def _parse_odometry(value: Any, field: str, declared: set[str]) -> dict[str, Odometry]:
    value = require_mapping(value, field)
    odometry = {}
    for name, odo in value.items():
        if name not in declared:
            raise InputError("assembly is not declared in 'assemblies'", field=f"{field}.{name}")
        odo = require_mapping(odo, f"{field}.{name}")
        for key in ("dp", "dtheta"):
            if key not in odo:
                raise InputError("missing", field=f"{field}.{name}.{key}")
        odometry[name] = Odometry(
            require_vector(odo["dp"], f"{field}.{name}.dp", 3, MAX_METRES),
            require_number(odo["dtheta"], f"{field}.{name}.dtheta", MAX_ANGLE),
        )
    return odometry


def _parse_detections(value: Any, field: str, cameras: dict[str, Camera]) -> dict[str, tuple[Detection, ...]]:
    value = require_mapping(value, field)
    detections = {}
    for key, dets in value.items():
        if key not in cameras:
            raise InputError("detections from an undeclared camera", field=f"{field}.{key}")
        parsed = []
        for k, det in enumerate(require_list(dets, f"{field}.{key}")):
            where = f"{field}.{key}[{k}]"
            det = require_mapping(det, where)
            for name in ("id", "u", "v", "r"):
                if name not in det:
                    raise InputError("missing", field=f"{where}.{name}")
            parsed.append(
                Detection(
                    node=require_int(det["id"], f"{where}.id"),
                    u=require_number(det["u"], f"{where}.u", MAX_PIXELS),
                    v=require_number(det["v"], f"{where}.v", MAX_PIXELS),
                    r=require_positive(det["r"], f"{where}.r", MIN_PIXELS, MAX_PIXELS),
                )
            )
        detections[key] = tuple(parsed)
    return detections


def _parse_mounts(value: Any, field: str, cameras: dict[str, Camera]) -> dict[str, Pose]:
    value = require_mapping(value, field)
    mounts = {}
    for key, pose in value.items():
        if key not in cameras:
            raise InputError("mount for an undeclared camera", field=f"{field}.{key}")
        mounts[key] = parse_pose(pose, f"{field}.{key}")
    return mounts


def parse_log(doc: Any) -> ObservationLog:
    """Validate a decoded ``decentral.log/1`` document and return it in memory."""
    doc = _check_format(doc, LOG_FORMAT)
    for key in ("node_radius", "assemblies", "steps"):
        if key not in doc:
            raise InputError("missing", field=key)
    radius = require_positive(doc["node_radius"], "node_radius", MIN_METRES, MAX_METRES)
    assemblies = require_mapping(doc["assemblies"], "assemblies")
    if not assemblies:
        raise InputError("no assemblies declared", field="assemblies")
    cameras = _parse_cameras(assemblies)
    declared = set(assemblies)
    steps = []
    previous_t = -np.inf
    raw_steps = require_list(doc["steps"], "steps")
    if not raw_steps:
        raise InputError("the log has no steps", field="steps")
    for k, raw in enumerate(raw_steps):
        field = f"steps[{k}]"
        raw = require_mapping(raw, field)
        for key in ("t", "config"):
            if key not in raw:
                raise InputError("missing", field=f"{field}.{key}")
        t = require_number(raw["t"], f"{field}.t", MAX_SECONDS)
        if t <= previous_t:
            raise InputError(f"step times must increase ({t:g} after {previous_t:g})", field=f"{field}.t")
        previous_t = t
        if k == 0 and raw.get("odometry"):  # motion since step k-1: there is no step -1
            raise InputError("the first step has no previous step to have moved from; leave its odometry out",
                             field=f"{field}.odometry")
        steps.append(
            Step(
                t=t,
                config=_parse_config(raw["config"], f"{field}.config", declared),
                odometry=_parse_odometry(raw.get("odometry", {}), f"{field}.odometry", declared),
                detections=_parse_detections(raw.get("detections", {}), f"{field}.detections", cameras),
                mounts=_parse_mounts(raw.get("mounts", {}), f"{field}.mounts", cameras),
            )
        )
    return ObservationLog(node_radius=radius, assemblies=tuple(assemblies), cameras=cameras, steps=tuple(steps))


def _pose_to_dict(pose: Pose) -> dict:
    return {"R": pose.R.tolist(), "p": pose.p.tolist()}


def log_to_dict(log: ObservationLog) -> dict:
    """Return the ``decentral.log/1`` document of ``log`` (inverse of :func:`parse_log`)."""
    log = require_log(log)
    assemblies: dict[str, dict] = {name: {} for name in log.assemblies}
    for camera in log.cameras.values():
        cams = assemblies[camera.assembly].setdefault("cameras", {})
        cams[camera.name] = {
            "K": camera.K.tolist(),
            "strut_in_root": _pose_to_dict(camera.strut_in_root),
            "cam_in_strut": _pose_to_dict(camera.cam_in_strut),
        }
    steps = []
    for k, step in enumerate(log.steps):
        raw: dict[str, Any] = {
            "t": step.t,
            "config": {a: {str(n): c.tolist() for n, c in nodes.items()} for a, nodes in step.config.items()},
        }
        if step.odometry and k:  # the first step's odometry (motion from before the log) is not written
            raw["odometry"] = {a: {"dp": o.dp.tolist(), "dtheta": o.dtheta} for a, o in step.odometry.items()}
        if step.mounts:
            raw["mounts"] = {key: _pose_to_dict(pose) for key, pose in step.mounts.items()}
        raw["detections"] = {
            key: [{"id": d.node, "u": d.u, "v": d.v, "r": d.r} for d in dets] for key, dets in step.detections.items()
        }
        steps.append(raw)
    return {"format": LOG_FORMAT, "node_radius": log.node_radius, "assemblies": assemblies, "steps": steps}


def write_log(path: str | os.PathLike, log: ObservationLog) -> None:
    """Write ``log`` as ``decentral.log/1`` atomically."""
    write_json_atomic(path, log_to_dict(log))


# --- decentral.estimate/1 --------------------------------------------------------------------


def poses_to_dict(poses) -> dict:
    """A step's poses (assembly -> :class:`PlanarPose`) as ``decentral.estimate/1`` writes them:
    ``{name: {"p": [x, y, z], "theta": rad}}``, in the mapping's order."""
    return {name: {"p": [float(x) for x in pose.p], "theta": float(pose.theta)} for name, pose in poses.items()}


def estimate_to_dict(estimate: Estimate) -> dict:
    """Return the ``decentral.estimate/1`` document of ``estimate``."""
    estimate = require_estimate(estimate)
    return {
        "format": ESTIMATE_FORMAT,
        "reference": estimate.reference,
        "steps": [
            {
                "t": step.t,
                "poses": poses_to_dict(step.poses),
                "unplaced": dict(step.unplaced),
            }
            for step in estimate.steps
        ],
        "stats": estimate.stats,
    }


def write_estimate(path: str | os.PathLike, estimate: Estimate) -> None:
    """Write ``estimate`` as ``decentral.estimate/1`` atomically.

    Examples
    --------
    >>> import os, tempfile
    >>> from decentral.estimator import estimate_log
    >>> from decentral.synthetic import camera, circle_motion, l_config, make_log
    >>> world = {"A": circle_motion(3, (0, 0), 1.0, 0.0, 0.1, 0.0), "B": circle_motion(3, (0, 0), 1.0, 0.8, 0.1, 0.0)}
    >>> log = make_log(world, {"A": l_config([0, 1, 2, 3]), "B": l_config([10, 11, 12, 13])}, [camera("A", yaw=0.5)])
    >>> path = os.path.join(tempfile.mkdtemp(), "estimate.json")
    >>> write_estimate(path, estimate_log(log))
    >>> back = read_estimate(path)
    >>> back.reference, sorted(back.steps[0].poses), back.stats["estimator"]
    ('A', ['B'], 'windowed-relaxation')
    """
    write_json_atomic(path, estimate_to_dict(estimate))


def parse_estimate(doc: Any) -> Estimate:
    """Validate a decoded ``decentral.estimate/1`` document."""
    doc = _check_format(doc, ESTIMATE_FORMAT)
    if not isinstance(doc.get("reference"), str):
        raise InputError("missing or not a string", field="reference")
    steps = []
    for k, raw in enumerate(require_list(doc.get("steps"), "steps")):
        raw = require_mapping(raw, f"steps[{k}]")
        poses = {}
        for name, pose in require_mapping(raw.get("poses", {}), f"steps[{k}].poses").items():
            pose = require_mapping(pose, f"steps[{k}].poses.{name}")
            poses[name] = PlanarPose(
                require_vector(pose.get("p"), f"steps[{k}].poses.{name}.p", 3, MAX_METRES),
                require_number(pose.get("theta"), f"steps[{k}].poses.{name}.theta", MAX_ANGLE),
            )
        unplaced = require_mapping(raw.get("unplaced", {}), f"steps[{k}].unplaced")
        for name, reason in unplaced.items():
            if not isinstance(reason, str):
                raise InputError("expected a reason string", field=f"steps[{k}].unplaced.{name}")
        steps.append(EstimateStep(require_number(raw.get("t"), f"steps[{k}].t", MAX_SECONDS), poses, dict(unplaced)))
    return require_estimate(Estimate(doc["reference"], tuple(steps), doc.get("stats", {})))


def read_estimate(path: str | os.PathLike) -> Estimate:
    """Read and validate a ``decentral.estimate/1`` file."""
    require_kind(path, ESTIMATE_FORMAT)
    doc = load_json(path)
    try:
        return parse_estimate(doc)
    except InputError as err:
        raise err.located(str(path)) from None
