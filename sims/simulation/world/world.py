"""The simulated world: assemblies' true trajectories and configurations, and their cameras.

A :class:`World` is the complete ground-truth timeline of a run (every step's root poses, shapes and
camera mounts), built once by a scenario; sensors then read it step by step. The world frame W is a
horizontal frame (z up) whose ``z = 0`` plane is the floor.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from decentral.observations import Camera, Pose
from sims.simulation.world.camera import CameraSpec
from decentral.geometry import rotz
from sims.simulation.world.shapes import Shape

__all__ = ["AssemblyTrack", "CameraRig", "World"]


@dataclass(frozen=True)
class AssemblyTrack:
    """True motion and configuration of one assembly over a run of T steps.

    Attributes
    ----------
    name : str
    floor_z : float
        Height [m] of the surface the assembly stands on; its root centre is at ``floor_z + r_0``.
    xy : ndarray, shape (T, 2)
        Root position in the world floor plane [m].
    yaw : ndarray, shape (T,)
        Root heading [rad]: yaw of R_{H_r}^W.
    shapes : tuple[Shape, ...]
        Configuration at each step (length T); the root id never changes.
    """

    name: str
    floor_z: float
    xy: np.ndarray
    yaw: np.ndarray
    shapes: tuple[Shape, ...]

    def root_pose(self, k: int, node_radius: float) -> Pose:
        """Pose of the root horizontal frame H_r in W at step ``k``."""
        p = np.array([self.xy[k, 0], self.xy[k, 1], self.floor_z + node_radius])
        return Pose(rotz(self.yaw[k]), p)


@dataclass(frozen=True)
class CameraRig:
    """A camera on an assembly's strut.

    Attributes
    ----------
    assembly, name : str
    spec : CameraSpec
        Intrinsics and sensing limits.
    strut_in_root : Pose
        Default pose of the strut S in H_r (what the log declares).
    cam_in_strut : Pose
        Pose of the camera c in S.
    mounts : tuple[Pose | None, ...]
        Per step, the strut pose in H_r when it differs from the default (reconfiguration moved
        the strut), else ``None``. Empty means "always the default".
    """

    assembly: str
    name: str
    spec: CameraSpec
    strut_in_root: Pose
    cam_in_strut: Pose
    mounts: tuple = ()

    @property
    def key(self) -> str:
        return f"{self.assembly}/{self.name}"

    def mount_at(self, k: int) -> Pose | None:
        """The overriding strut pose at step ``k`` or ``None``."""
        return self.mounts[k] if self.mounts else None

    def in_root(self, k: int) -> Pose:
        """Pose of the camera in H_r at step ``k``."""
        return (self.mount_at(k) or self.strut_in_root).compose(self.cam_in_strut)

    def as_camera(self) -> Camera:
        """The log's declaration of this camera."""
        return Camera(self.assembly, self.name, self.spec.K.copy(), self.strut_in_root, self.cam_in_strut)


@dataclass(frozen=True)
class World:
    """Ground truth of a whole run.

    Attributes
    ----------
    node_radius : float
        r_0 [m].
    times : ndarray, shape (T,)
        Step times [s], strictly increasing.
    assemblies : tuple[AssemblyTrack, ...]
        In log order (the first is the default reference).
    cameras : tuple[CameraRig, ...]
    meta : dict
        Free-form description (scenario name, parameters), copied into the truth file.
    """

    node_radius: float
    times: np.ndarray
    assemblies: tuple[AssemblyTrack, ...]
    cameras: tuple[CameraRig, ...]
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        names = [a.name for a in self.assemblies]
        if len(set(names)) != len(names):
            raise ValueError("assembly names must be unique")
        T = len(self.times)
        for a in self.assemblies:
            if len(a.shapes) != T or len(a.xy) != T or len(a.yaw) != T:
                raise ValueError(f"assembly {a.name}: track length differs from the number of steps")
        for k in range(T):
            seen: set[int] = set()
            for a in self.assemblies:
                ids = set(a.shapes[k].ids)
                if ids & seen:
                    raise ValueError(f"step {k}: node ids {sorted(ids & seen)} used by two assemblies")
                seen |= ids

    @property
    def steps(self) -> int:
        return len(self.times)

    def assembly(self, name: str) -> AssemblyTrack:
        """The track called ``name``."""
        for a in self.assemblies:
            if a.name == name:
                return a
        raise KeyError(name)

    def root_pose(self, name: str, k: int) -> Pose:
        """Pose of assembly ``name``'s root frame H_r in W at step ``k``."""
        return self.assembly(name).root_pose(k, self.node_radius)

    def nodes_in_world(self, k: int):
        """All node centres at step ``k``.

        Returns
        -------
        ids : ndarray, shape (N,) int
        owners : list[str], length N
        centres : ndarray, shape (N, 3)
            Centres in W [m].
        """
        ids, owners, centres = [], [], []
        for a in self.assemblies:
            pose = a.root_pose(k, self.node_radius)
            shape = a.shapes[k]
            ids.extend(shape.ids)
            owners.extend([a.name] * len(shape.ids))
            centres.append(pose.apply(shape.centres))
        return np.asarray(ids, dtype=int), owners, np.concatenate(centres, axis=0)

    def camera_in_world(self, rig: CameraRig, k: int) -> Pose:
        """Pose of ``rig``'s camera frame in W at step ``k``."""
        return self.root_pose(rig.assembly, k).compose(rig.in_root(k))
