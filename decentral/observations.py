"""In-memory form of an observation log (contract ``decentral.log/1``) and of an estimate.

These are plain frozen containers over numpy arrays; reading and writing the JSON files lives in
:mod:`sims.io`. Frames follow the contract: a pose "of B in A" is ``(R, p)`` with ``x_A = R x_B + p``;
horizontal frames have z up; camera frames follow OpenCV (x right, y down, z forward).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

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

    ``dp`` (3,) is p̂_{H_r,k}^{H_r,k-1}; ``dtheta`` the yaw of R̂_{H_r,k}^{H_r,k-1} (seed 000 §II).
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
    :data:`decentral.placement.REASONS`, e.g. ``{"A2": "yaw_std_above_limit"}``.
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
