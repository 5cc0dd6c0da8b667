"""The AprilTag-pose baseline of Liu et al. 2024 §V-C 1: target pose from the tag on its root node.

For each step, the tag read on a target's root node gives the tag's pose in the camera from its
four image corners (``cv2.solvePnPGeneric`` with ``SOLVEPNP_IPPE_SQUARE``, and SQPnP as a check,
the lower reprojection error winning; the tag taken as a flat square:
precisely what a sticker bent around a sphere is not, Liu et al. 2024 §III-B). The node centre lies
``depth`` behind the tag along its normal (``depth`` = distance from the sphere centre to the plane
of the print's four corners), the camera's mounting maps it into the observer's root frame, and
the target root is that node (the root node sits at the origin of H_r). The yaw is the tag's right
axis measured in the root frame, minus the sticker's own azimuth on the node; since copies of the
tag sit all around the equator, it is ambiguous by the sticker spacing, and is resolved towards the
previous step's estimate (Liu et al. 2024 reports no angular error for this baseline).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping, Sequence

import cv2
import numpy as np

from agents.perception.sphere_tags import StickerLayout
from decentral.observations import Estimate, EstimateStep, ObservationLog, PlanarPose

__all__ = ["TagPoseConfig", "print_geometry", "tag_pose", "estimate_log_tag_pose"]


def print_geometry(layout: StickerLayout, node_radius: float) -> tuple[float, float]:
    """Side of the square through a print's four outer corners, and its plane's distance from the
    sphere centre (m), for prints spanning ``2 half_angle`` in both tangent angles."""
    t = np.tan(layout.half_angle)
    k = np.sqrt(1.0 + 2.0 * t * t)
    return 2.0 * node_radius * t / k, node_radius / k


@dataclass(frozen=True)
class TagPoseConfig:
    """Parameters of the baseline: the sticker layout (print size, azimuths) and corner source."""

    layout: StickerLayout = field(default_factory=StickerLayout.around)


def tag_pose(corners: np.ndarray, K: np.ndarray, side: float) -> tuple[np.ndarray, np.ndarray] | None:
    """Pose of a square tag in the camera from its corners.

    Parameters
    ----------
    corners : ndarray, shape (4, 2)
        Image corners in canonical order (top-left, top-right, bottom-right, bottom-left).
    K : ndarray, shape (3, 3)
    side : float
        Side of the square (m).

    Returns
    -------
    (R, t) or None
        Rotation (3, 3) of the tag frame in the camera (x right, y up along the tag, z out of it
        towards the viewer) and its centre (3,) in the camera, m.
    """
    h = side / 2.0
    obj = np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])
    img = np.asarray(corners, dtype=np.float64).reshape(4, 1, 2)
    if not np.all(np.isfinite(img)):
        return None
    K = np.asarray(K, dtype=np.float64)
    best = None
    # OpenCV 5.0.0's IPPE_SQUARE returned a 0.58 px-error pose on exact synthetic corners (where
    # SQPnP is exact): keep the lowest-error solution of both solvers
    for flag in (cv2.SOLVEPNP_IPPE_SQUARE, cv2.SOLVEPNP_SQPNP):
        try:
            n, rvecs, tvecs, errs = cv2.solvePnPGeneric(obj, img, K, None, flags=flag)
        except cv2.error:
            continue
        for rvec, tvec, err in zip(rvecs, tvecs, np.asarray(errs).reshape(-1)):
            if np.all(np.isfinite(tvec)) and tvec.ravel()[2] > 0 and (best is None or err < best[0]):
                best = (float(err), rvec, tvec)
    if best is None:
        return None
    R, _ = cv2.Rodrigues(best[1])
    return R, best[2].ravel()


def _wrap(a: float) -> float:
    return float((a + np.pi) % (2.0 * np.pi) - np.pi)


def estimate_log_tag_pose(
    log: ObservationLog,
    reads: Mapping[str, Sequence[Mapping[int, np.ndarray]]],
    config: TagPoseConfig = TagPoseConfig(),
    *,
    reference: str | None = None,
) -> Estimate:
    """Run the AprilTag-pose baseline over a log.

    Parameters
    ----------
    log : ObservationLog
        Cameras, configurations (which node is each target's root) and node radius; its detections
        are not used.
    reads : mapping
        Camera key -> per step, node id -> tag corners (4, 2) read in that camera's frame.
        Only cameras on the reference assembly are used.
    reference : str, optional
        The assembly the poses are relative to (default: the first of the log).

    Returns
    -------
    Estimate
        Per step, the targets whose root node's tag was read; ``stats`` counts reads used.
    """
    reference = reference or log.assemblies[0]
    side, depth = print_geometry(config.layout, log.node_radius)
    axes = np.asarray(config.layout.axes, dtype=float)
    right = np.asarray(config.layout.right, dtype=float)
    equator = np.abs(axes[:, 2]) < 0.5
    azimuth = np.arctan2(right[:, 1], right[:, 0])  # the sticker's right axis in the node frame
    previous: dict[str, float] = {}
    steps, used, failed = [], 0, 0
    for k, step in enumerate(log.steps):
        roots = {}
        for name, nodes in step.config.items():
            if name == reference:
                continue
            for node, offset in nodes.items():
                if np.linalg.norm(offset) < 1e-9:
                    roots[node] = name
        poses: dict[str, PlanarPose] = {}
        for key, per_step in reads.items():
            cam = log.cameras.get(key)
            if cam is None or cam.assembly != reference or k >= len(per_step):
                continue
            mount = log.camera_pose(key, step)
            for node, corners in per_step[k].items():
                name = roots.get(int(node))
                if name is None or name in poses:
                    continue
                pose = tag_pose(corners, cam.K, side)
                if pose is None:
                    failed += 1
                    continue
                R_tc, t_tc = pose
                centre_cam = t_tc - depth * R_tc[:, 2]  # behind the print, along its outward normal
                p = mount.R @ centre_cam + mount.p
                right_root = mount.R @ R_tc[:, 0]
                normal_root = mount.R @ R_tc[:, 2]
                yaw_tag = float(np.arctan2(right_root[1], right_root[0]))
                if normal_root[2] > 0.7 and (~equator).any():
                    cands = [yaw_tag - azimuth[i] for i in np.flatnonzero(~equator)]
                else:
                    cands = [yaw_tag - azimuth[i] for i in np.flatnonzero(equator)]
                ref = previous.get(name, 0.0)
                theta = _wrap(min(cands, key=lambda a: abs(_wrap(a - ref))))
                previous[name] = theta
                poses[name] = PlanarPose(p, theta)
                used += 1
        steps.append(EstimateStep(step.t, poses))
    return Estimate(reference, tuple(steps), {"method": "apriltag-pose", "reads_used": used, "pnp_failures": failed,
                                             "print_side_m": side, "print_depth_m": depth})
