"""A tiny, exact observation-log generator: the examples, conformance checks and unit tests of the estimators.

Given world poses of assembly roots per step (yaw, position), node configurations and cameras, it
produces detections by inverting Liu et al. 2024 eq. (1): (u, v) the projection of the node centre and
r = f r0 / z_c; optional Gaussian noise on (u, v, r) and on odometry.
"""

from __future__ import annotations

import numpy as np

from decentral.geometry import rotz, wrap_angle
from decentral.observations import Camera, Detection, ObservationLog, Odometry, Pose, Step

__all__ = ["K_DEFAULT", "R_CAM_IN_STRUT", "camera", "circle_motion", "l_config", "line_config", "make_log", "true_relative"]

R_CAM_IN_STRUT = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # looks along strut +x
K_DEFAULT = np.array([[760.0, 0.0, 512.0], [0.0, 760.0, 384.0], [0.0, 0.0, 1.0]])


def camera(assembly: str, name: str = "cam0", yaw: float = 0.0, p=(0.09, 0.0, 0.05)) -> Camera:
    """A forward camera on a strut of ``assembly`` yawed by ``yaw`` in its root frame."""
    return Camera(assembly, name, K_DEFAULT.copy(), Pose(rotz(yaw), np.array(p, float)),
                  Pose(R_CAM_IN_STRUT.copy(), np.array([0.05, 0.0, 0.04])))


def make_log(world: dict[str, list[tuple[float, np.ndarray]]], configs: dict[str, dict[int, np.ndarray]],
             cameras: list[Camera], *, node_radius: float = 0.06, dt: float = 0.2,
             rng: np.random.Generator | None = None, sigma_px: float = 0.0, sigma_r: float = 0.0,
             sigma_odo: float = 0.0, sigma_yaw: float = 0.0, config_at=None, order=None,
             width: int = 1024, height: int = 768) -> ObservationLog:
    """Build a log from world poses ``world[name][k] = (yaw, p)``.

    ``config_at(k)`` may return a per-step configuration (for reconfiguration); ``order`` lists the
    assemblies in the log's declared order (first = default reference).
    """
    names = list(order or world)
    n_steps = len(next(iter(world.values())))
    steps = []
    for k in range(n_steps):
        config = config_at(k) if config_at else configs
        dets = {}
        for cam in cameras:
            yaw_o, p_o = world[cam.assembly][k]
            cam_world = Pose(rotz(yaw_o), np.asarray(p_o, float)).compose(cam.in_root())
            found = []
            for target, nodes in config.items():
                if target == cam.assembly:
                    continue
                yaw_t, p_t = world[target][k]
                for node, q in nodes.items():
                    x_world = rotz(yaw_t) @ q + p_t
                    x_cam = cam_world.R.T @ (x_world - cam_world.p)
                    if x_cam[2] <= 0.1:
                        continue
                    uvw = cam.K @ x_cam
                    u, v = uvw[0] / uvw[2], uvw[1] / uvw[2]
                    r = cam.K[0, 0] * node_radius / x_cam[2]
                    if not (0 <= u < width and 0 <= v < height):
                        continue
                    if rng is not None:
                        u += rng.normal(0, sigma_px) if sigma_px else 0.0
                        v += rng.normal(0, sigma_px) if sigma_px else 0.0
                        r += rng.normal(0, sigma_r) if sigma_r else 0.0
                    found.append(Detection(node, float(u), float(v), float(max(r, 0.5))))
            dets[cam.key] = tuple(found)
        odometry = {}
        if k:
            for name in names:
                (y0, p0), (y1, p1) = world[name][k - 1], world[name][k]
                dp = rotz(y0).T @ (np.asarray(p1) - np.asarray(p0))
                dth = float(wrap_angle(y1 - y0))
                if rng is not None and (sigma_odo or sigma_yaw):
                    dp = dp + rng.normal(0, sigma_odo, 3) * np.array([1, 1, 0.2])
                    dth += rng.normal(0, sigma_yaw)
                odometry[name] = Odometry(dp, dth)
        steps.append(Step(k * dt, {a: dict(n) for a, n in config.items()}, odometry, dets))
    return ObservationLog(node_radius, tuple(names), {c.key: c for c in cameras}, tuple(steps))


def circle_motion(n: int, centre, radius: float, phase: float, speed: float, z: float, spin: float = 0.0):
    """World poses along a circle arc: yaw tangent to the path plus ``spin`` rad/step."""
    out = []
    for k in range(n):
        a = phase + speed * k
        p = np.array([centre[0] + radius * np.cos(a), centre[1] + radius * np.sin(a), z])
        out.append((a + np.pi / 2 + spin * k, p))
    return out


def line_config(ids, spacing: float = 0.2) -> dict[int, np.ndarray]:
    """Nodes ``ids`` on a line along x, ``spacing`` m apart (root frame)."""
    return {i: np.array([spacing * k, 0.0, 0.0]) for k, i in enumerate(ids)}


def l_config(ids, spacing: float = 0.2) -> dict[int, np.ndarray]:
    """Up to six nodes ``ids`` in an L-like shape on a ``spacing`` m grid (root frame)."""
    pts = [(0, 0), (1, 0), (1, 1), (2, 1), (0, -1), (2, 2)]
    return {i: np.array([spacing * x, spacing * y, 0.0]) for i, (x, y) in zip(ids, pts)}


def true_relative(world, name: str, reference: str, k: int) -> tuple[np.ndarray, float]:
    """Ground-truth pose of ``name`` in ``reference``'s root frame at step ``k`` (eq. (19))."""
    (yr, pr), (ya, pa) = world[reference][k], world[name][k]
    return rotz(yr).T @ (np.asarray(pa) - np.asarray(pr)), float(wrap_angle(ya - yr))
