"""Camera mounts and pose algebra of the simulator (yaw rotations are :mod:`decentral.geometry`'s).

Frames follow the contract: a pose of B in A is ``(R, p)`` with ``x_A = R x_B + p``; horizontal
frames have z up; camera frames follow OpenCV (x right, y down, z forward).
"""

from __future__ import annotations

import numpy as np

from decentral.observations import Pose

__all__ = ["rot_y", "CAM_LOOKS_ALONG_X", "camera_mount", "inverse"]

#: camera-in-strut rotation that makes an OpenCV camera look along the strut's +x with image "down"
#: along the strut's -z (the contract's example ``cam_in_strut``).
CAM_LOOKS_ALONG_X = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def rot_y(phi: float) -> np.ndarray:
    """Rotation (3, 3) by ``phi`` rad about y (positive ``phi`` tips +x towards -z)."""
    c, s = np.cos(phi), np.sin(phi)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def camera_mount(pitch_down: float = 0.0, offset=(0.05, 0.0, 0.04)) -> Pose:
    """Pose of a camera in its strut: looking along the strut's +x, tilted down by ``pitch_down`` rad."""
    return Pose(rot_y(pitch_down) @ CAM_LOOKS_ALONG_X, np.asarray(offset, dtype=float))


def inverse(pose: Pose) -> Pose:
    """Return the pose of A in B given ``pose`` = B in A."""
    return Pose(pose.R.T, -pose.R.T @ pose.p)
