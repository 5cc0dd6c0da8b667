"""Helpers that place cameras on assemblies' struts."""

from __future__ import annotations

import numpy as np

from decentral.observations import Pose
from sims.simulation.world.camera import CameraSpec, default_K
from decentral.geometry import rotz
from sims.simulation.world.mounts import camera_mount
from sims.simulation.world.world import CameraRig

__all__ = ["strut_camera"]


def strut_camera(
    assembly: str,
    name: str,
    *,
    at,
    look_yaw: float,
    pitch_down: float = 0.0,
    spec: CameraSpec | None = None,
    mounts: tuple = (),
) -> CameraRig:
    """A camera on a strut at ``at`` (3,) in H_r, whose frame S is turned ``look_yaw`` rad about z.

    The camera looks along the strut frame's +x (the contract's ``cam_in_strut`` rotation), tilted
    down by ``pitch_down`` rad, 5 cm ahead of and 4 cm above the strut frame's origin.
    """
    strut = Pose(rotz(look_yaw), np.asarray(at, dtype=float))
    return CameraRig(assembly, name, spec or CameraSpec(default_K()), strut, camera_mount(pitch_down), tuple(mounts))
