"""In-memory form of an observation log (contract ``decentral.log/1``) and of an estimate.

These are plain frozen containers over numpy arrays; reading and writing the JSON files lives in
:mod:`sims.io`. Frames follow the contract: a pose "of B in A" is ``(R, p)`` with ``x_A = R x_B + p``;
horizontal frames have z up; camera frames follow OpenCV (x right, y down, z forward).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from decentral.errors import InputError

__all__ = [
    "Pose",
    "Camera",
    "Detection",
    "Odometry",
    "Step",
    "ObservationLog",
    "PlanarPose",
    "EstimateStep",
    "Estimate",
    "require_log",
    "require_estimate",
    "require_increasing_times",
    "resolve_reference",
]


@dataclass(frozen=True)
class Pose:
    """A rigid pose of frame B in frame A: ``R`` (3, 3) rotation, ``p`` (3,) translation."""

    R: np.ndarray
    p: np.ndarray

    def apply(self, x: np.ndarray) -> np.ndarray:
        """Map points ``x`` (..., 3) written in B to A."""
        return x @ self.R.T + self.p

    def compose(self, other: "Pose") -> "Pose":
        """Return the pose of C in A, given ``self`` = B in A and ``other`` = C in B."""
        return Pose(self.R @ other.R, self.R @ other.p + self.p)


@dataclass(frozen=True)
class Camera:
    """A pinhole camera mounted on an assembly's strut.

    Attributes
    ----------
    assembly, name : str
        Owner assembly and camera name; its key in a log is ``"assembly/name"``.
    K : ndarray, shape (3, 3)
        Pinhole intrinsics.
    strut_in_root : Pose
        Pose of the camera strut S in the assembly's root horizontal frame H_r.
    cam_in_strut : Pose
        Pose of the camera frame c in the strut S.
    """

    assembly: str
    name: str
    K: np.ndarray
    strut_in_root: Pose
    cam_in_strut: Pose

    @property
    def key(self) -> str:
        return f"{self.assembly}/{self.name}"

    def in_root(self, strut_in_root: Pose | None = None) -> Pose:
        """Pose of the camera in H_r, optionally with a step's overriding strut mount."""
        return (strut_in_root or self.strut_in_root).compose(self.cam_in_strut)


@dataclass(frozen=True)
class Detection:
    """One identified node detection: image centre ``(u, v)`` and radius ``r`` in pixels."""

    node: int
    u: float
    v: float
    r: float


@dataclass(frozen=True)
class Odometry:
    """Root motion since the previous step, written in the root frame at the previous step.

    ``dp`` (3,) is p̂_{H_r,k}^{H_r,k-1}; ``dtheta`` the yaw of R̂_{H_r,k}^{H_r,k-1} (Liu et al. 2024 §II).
    """

    dp: np.ndarray
    dtheta: float


@dataclass(frozen=True)
class Step:
    """What every assembly knows at one time step.

    Attributes
    ----------
    t : float
        Time in seconds (strictly increasing along a log).
    config : dict[str, dict[int, ndarray]]
        Per assembly, node id -> node centre (3,) in the assembly's root horizontal frame.
    odometry : dict[str, Odometry]
        Per assembly with odometry at this step (absent at the first step).
    detections : dict[str, tuple[Detection, ...]]
        Per camera key ``"assembly/camera"``, its identified detections of this frame.
    mounts : dict[str, Pose]
        Per camera key, a strut pose in H_r overriding the camera's default at this step.
    """

    t: float
    config: dict[str, dict[int, np.ndarray]]
    odometry: dict[str, Odometry] = field(default_factory=dict)
    detections: dict[str, tuple[Detection, ...]] = field(default_factory=dict)
    mounts: dict[str, Pose] = field(default_factory=dict)

    def node_owner(self) -> dict[int, str]:
        """Map node id -> assembly at this step."""
        return {node: name for name, nodes in self.config.items() for node in nodes}

    def stray_detections(self) -> int:
        """Number of detections whose id is in no assembly's configuration at this step (stray tags)."""
        owner = self.node_owner()
        return sum(det.node not in owner for dets in self.detections.values() for det in dets)


@dataclass(frozen=True)
class ObservationLog:
    """A whole observation log: node radius, assemblies in order, cameras, and steps."""

    node_radius: float
    assemblies: tuple[str, ...]
    cameras: dict[str, Camera]
    steps: tuple[Step, ...]

    def camera_pose(self, key: str, step: Step) -> Pose:
        """Pose of camera ``key`` in its assembly's root frame at ``step`` (mount override applied)."""
        return self.cameras[key].in_root(step.mounts.get(key))


@dataclass(frozen=True)
class PlanarPose:
    """A 4-DoF pose of one root horizontal frame in another: ``p`` (3,), yaw ``theta`` (rad)."""

    p: np.ndarray
    theta: float


@dataclass(frozen=True)
class EstimateStep:
    """Poses relative to the reference at one step; assemblies that cannot be placed are absent.

    ``unplaced`` says why each absent assembly (other than the reference) is absent: a reason code of
    :data:`decentral.unplaced.REASONS`, e.g. ``{"A2": "yaw_std_above_limit"}``.
    """

    t: float
    poses: dict[str, PlanarPose]
    unplaced: dict[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class Estimate:
    """Contract ``decentral.estimate/1`` in memory: reference, steps, free-form stats."""

    reference: str
    steps: tuple[EstimateStep, ...]
    stats: dict


def _hint(value: object, kind: str) -> str:
    got = type(value).__name__
    if isinstance(value, dict):
        return (f"expected an {kind}, got a dict: a decoded JSON document is not one; read files with "
                f"sims.io.log_json.read_log/read_estimate or parse documents with parse_log/parse_estimate")
    return f"expected an {kind}, got {got}"


def _check_pose(pose: object, field: str) -> None:
    if not isinstance(pose, Pose):
        raise InputError(f"expected a Pose, got {type(pose).__name__}", field=field)
    R, p = np.asarray(pose.R), np.asarray(pose.p)
    if R.shape != (3, 3) or p.shape != (3,) or not (np.all(np.isfinite(R)) and np.all(np.isfinite(p))):
        raise InputError("R must be a finite 3x3 array and p a finite (3,) array", field=field)
    if np.abs(R.T @ R - np.eye(3)).max() > 1e-6 or np.linalg.det(R) < 0:
        raise InputError("is not a 3x3 rotation matrix (R^T R != I or det != +1)", field=f"{field}.R")


def _check_vector(value: object, field: str) -> None:
    arr = np.asarray(value) if isinstance(value, np.ndarray) else None
    if arr is None or arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise InputError(f"expected a finite numpy array of shape (3,), got {type(value).__name__}", field=field)


def _check_step(step: object, k: int, log: "ObservationLog") -> None:
    where = f"steps[{k}]"
    if not isinstance(step, Step):
        raise InputError(f"expected a Step, got {type(step).__name__}", field=where)
    if not isinstance(step.t, (int, float, np.floating, np.integer)) or not np.isfinite(step.t):
        raise InputError("must be a finite number", field=f"{where}.t")
    for name, nodes in step.config.items():
        if name not in log.assemblies or not isinstance(nodes, dict):
            raise InputError("an assembly of the log mapping node id -> centre", field=f"{where}.config.{name}")
        for node, centre in nodes.items():
            if not isinstance(node, (int, np.integer)):
                raise InputError("node ids must be integers", field=f"{where}.config.{name}.{node!r}")
            _check_vector(centre, f"{where}.config.{name}.{node}")
    for name, odo in step.odometry.items():
        if name not in log.assemblies or not isinstance(odo, Odometry):
            raise InputError("expected an Odometry of an assembly of the log", field=f"{where}.odometry.{name}")
        _check_vector(odo.dp, f"{where}.odometry.{name}.dp")
        if not np.isfinite(odo.dtheta):
            raise InputError("must be finite", field=f"{where}.odometry.{name}.dtheta")
    for key, dets in step.detections.items():
        if key not in log.cameras or not isinstance(dets, (tuple, list)):
            raise InputError("detections of an undeclared camera, or not a tuple", field=f"{where}.detections.{key}")
        for i, d in enumerate(dets):
            if not isinstance(d, Detection) or not (np.isfinite(d.u) and np.isfinite(d.v) and d.r > 0):
                raise InputError("expected a Detection with finite u, v and r > 0",
                                 field=f"{where}.detections.{key}[{i}]")
    for key, pose in step.mounts.items():
        if key not in log.cameras:
            raise InputError("mount for an undeclared camera", field=f"{where}.mounts.{key}")
        _check_pose(pose, f"{where}.mounts.{key}")


def require_log(log: object) -> ObservationLog:
    """Return ``log`` if it is a well-formed :class:`ObservationLog`, else raise :class:`InputError`.

    Checks what the estimators rely on (the contract's rules for ``decentral.log/1``): types and
    shapes, finite numbers, rotations, a positive node radius, increasing step times, and that every
    configuration, odometry, detection and mount names a declared assembly or camera.
    """
    if not isinstance(log, ObservationLog):
        raise InputError(_hint(log, "ObservationLog"), field="log")
    if not (isinstance(log.node_radius, (int, float, np.floating)) and np.isfinite(log.node_radius)
            and log.node_radius > 0):
        raise InputError("must be a positive number", field="node_radius")
    if not log.assemblies or not all(isinstance(a, str) for a in log.assemblies):
        raise InputError("must be a non-empty tuple of names", field="assemblies")
    for key, cam in log.cameras.items():
        if not isinstance(cam, Camera) or cam.key != key or cam.assembly not in log.assemblies:
            raise InputError("expected a Camera of a declared assembly under its key 'assembly/name'",
                             field=f"cameras.{key}")
        K = np.asarray(cam.K)
        if K.shape != (3, 3) or not np.all(np.isfinite(K)) or abs(np.linalg.det(K)) < 1e-9:
            raise InputError("K must be a finite, non-singular 3x3 array", field=f"cameras.{key}.K")
        _check_pose(cam.strut_in_root, f"cameras.{key}.strut_in_root")
        _check_pose(cam.cam_in_strut, f"cameras.{key}.cam_in_strut")
    if not log.steps:
        raise InputError("the log has no steps", field="steps")
    for k, step in enumerate(log.steps):
        _check_step(step, k, log)
    require_increasing_times([step.t for step in log.steps])
    return log


def require_increasing_times(times: Sequence[float], field: str = "steps") -> None:
    """Raise :class:`InputError` naming ``{field}[k].t`` at the first time that does not exceed the one before.

    Logs, estimates and ground truths all key their steps by time; a repeated or backward time would
    make two steps indistinguishable (docs/formats.md: "step times that do not increase" are bad input).
    """
    previous = -np.inf
    for k, t in enumerate(times):
        if not t > previous:
            raise InputError(f"step times must increase ({t:g} after {previous:g})", field=f"{field}[{k}].t")
        previous = t


def require_estimate(estimate: object) -> Estimate:
    """Return ``estimate`` if it is an :class:`Estimate` whose poses are :class:`PlanarPose` s and whose
    step times increase, else raise :class:`InputError` naming the field (``steps[2].t``)."""
    if not isinstance(estimate, Estimate):
        raise InputError(_hint(estimate, "Estimate"), field="estimate")
    for k, step in enumerate(estimate.steps):
        if not isinstance(step, EstimateStep):
            raise InputError(f"expected an EstimateStep, got {type(step).__name__}", field=f"steps[{k}]")
        for name, pose in step.poses.items():
            if not isinstance(pose, PlanarPose):
                raise InputError(f"expected a PlanarPose, got {type(pose).__name__}", field=f"steps[{k}].poses.{name}")
    require_increasing_times([step.t for step in estimate.steps])
    return estimate


def resolve_reference(log: ObservationLog, reference: object) -> str:
    """The reference assembly's name: ``reference`` if it names one of ``log``'s assemblies, the first if None."""
    if reference is None:
        return log.assemblies[0]
    if not isinstance(reference, str) or reference not in log.assemblies:
        raise InputError(f"unknown reference assembly {reference!r}", field="reference")
    return reference
