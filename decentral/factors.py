"""Visual and odometry factors of Liu et al. 2024 §IV-A/B, generalized to many assemblies and cameras.

A *variable* is one assembly's root horizontal frame at one step, ``(assembly, step)``: a yaw
rotation ``R = blkdiag(R2, 1)`` and a position ``p`` in an arbitrary common horizontal frame.

Visual factor (Liu et al. 2024 eq. (2)-(4)), camera on observer ``o`` seeing node ``n`` of target ``a``:

.. math:: e = R_a q_n + p_a - p_o - R_o t_n,

with ``q_n = p_{N_n}^{H_ar}`` the node's configured centre and ``t_n = p_c^{H_or} + R_c^{H_or} \\hat p^c``
the back-projected centre (eq. (1)) written in the observer's root frame (eq. (4)'s ``t_i``).

Odometry factor (eq. (6)-(7)), assembly ``a`` from step ``k-1`` (variable ``v``) to ``k`` (``u``):

.. math:: e_p = p_u - p_v - R_v \\hat p, \\qquad E_R = R_u - R_v \\hat R.

Each residual is linear in the stacked unknowns, so the window cost is a quadratic form (eq. (5),
(8), (11)). Because every rotation is a yaw (eq. (15c)), the z rows of the residuals do not involve
the rotations at all: the cost splits exactly into an xy part over ``[P_xy, R2_1..R2_m]`` (the
planar SE-Sync form handled by :mod:`decentral.relaxation`) and a z part over ``P_z`` alone, a
weighted Laplacian least-squares problem that shares its matrix with the xy positions.

Weights: ``unit`` reproduces the paper's unweighted sums; ``information`` (default) scales each
residual by an isotropic inverse variance (a detection's variance grows with depth as the radius
cue weakens), which keeps the quadratic structure intact.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from decentral.geometry import backproject, rot2
from decentral.noise import NoiseModel
from decentral.observations import ObservationLog, require_log

__all__ = [
    "NoiseModel",
    "VisualMeasurements",
    "OdometryMeasurement",
    "StepMeasurements",
    "measure_log",
    "detection_weights",
]


def detection_weights(depth: np.ndarray, r: np.ndarray, f: float, noise: NoiseModel) -> np.ndarray:
    """Isotropic inverse variances (n,) of back-projected node centres.

    Lateral std. ``z sigma_pixel / f``, depth std. ``z sigma_radius / r`` (first-order propagation of
    eq. (1)); the weight is the inverse of their mean variance over the three axes.
    """
    if noise.weighting == "unit":
        return np.ones_like(depth)
    lateral = depth * noise.sigma_pixel / f
    along = depth * noise.sigma_radius / r
    return 3.0 / (2.0 * lateral**2 + along**2)


@dataclass(frozen=True)
class VisualMeasurements:
    """All visual factors of one step, as arrays over its ``n`` usable detections.

    ``observer``/``target`` are assembly names per detection; ``node`` the node ids; ``q`` (n, 3)
    the node centres in the target's root frame; ``t`` (n, 3) the measured centres in the observer's
    root frame (eq. (4)); ``bearing`` (n, 3) unit rays in the observer's root frame and ``origin``
    (n, 3) the camera centres there (for bearing-only estimators); ``weight`` (n,).
    """

    observer: tuple[str, ...]
    target: tuple[str, ...]
    node: np.ndarray
    q: np.ndarray
    t: np.ndarray
    bearing: np.ndarray
    origin: np.ndarray
    weight: np.ndarray

    def __len__(self) -> int:
        return len(self.observer)


@dataclass(frozen=True)
class OdometryMeasurement:
    """Odometry of one assembly into one step: ``dp`` (3,), ``dtheta`` and their weights."""

    dp: np.ndarray
    dtheta: float
    weight_p: float
    weight_R: float


@dataclass(frozen=True)
class StepMeasurements:
    """Everything the estimators use from one log step."""

    t: float
    visual: VisualMeasurements
    odometry: dict[str, OdometryMeasurement]
    stray: int = 0
    self_seen: int = 0
    config: dict[str, dict[int, np.ndarray]] = field(default_factory=dict)


def _empty_visual() -> VisualMeasurements:
    z3 = np.zeros((0, 3))
    return VisualMeasurements((), (), np.zeros(0, int), z3, z3, z3, z3, np.zeros(0))


def measure_log(log: ObservationLog, noise: NoiseModel = NoiseModel()) -> list[StepMeasurements]:
    """Turn every step of ``log`` into factor measurements (back-projection, frames, weights).

    Detections whose id belongs to no assembly at that step (stray tags) are skipped and counted;
    so are detections of an observer's own nodes (they carry no relative information).
    """
    log = require_log(log)
    w_p, w_R = noise.odometry_weights()
    out = []
    for step in log.steps:
        owner = step.node_owner()
        rows: dict[str, list] = {k: [] for k in ("observer", "target", "node", "q", "t", "bearing", "origin", "w")}
        stray, self_seen = step.stray_detections(), 0
        for key, dets in step.detections.items():
            if not dets:
                continue
            camera = log.cameras[key]
            keep = []
            for det in dets:
                target = owner.get(det.node)
                if target is None:
                    continue
                if target == camera.assembly:
                    self_seen += 1
                else:
                    keep.append((det, target))
            if not keep:
                continue
            u = np.array([d.u for d, _ in keep])
            v = np.array([d.v for d, _ in keep])
            r = np.array([d.r for d, _ in keep])
            p_cam = backproject(camera.K, u, v, r, log.node_radius)  # Liu et al. 2024 eq. (1)
            pose = log.camera_pose(key, step)
            rows["t"].append(pose.apply(p_cam))  # eq. (4): t_i in the observer's root frame
            rays = p_cam / np.linalg.norm(p_cam, axis=1, keepdims=True)
            rows["bearing"].append(rays @ pose.R.T)
            rows["origin"].append(np.repeat(pose.p[None], len(keep), 0))
            f = 0.5 * (camera.K[0, 0] + camera.K[1, 1])
            rows["w"].append(detection_weights(p_cam[:, 2], r, f, noise))
            for det, target in keep:
                rows["observer"].append(camera.assembly)
                rows["target"].append(target)
                rows["node"].append(det.node)
                rows["q"].append(step.config[target][det.node])
        if rows["observer"]:
            visual = VisualMeasurements(
                observer=tuple(rows["observer"]),
                target=tuple(rows["target"]),
                node=np.array(rows["node"]),
                q=np.array(rows["q"]),
                t=np.vstack(rows["t"]),
                bearing=np.vstack(rows["bearing"]),
                origin=np.vstack(rows["origin"]),
                weight=np.concatenate(rows["w"]),
            )
        else:
            visual = _empty_visual()
        odometry = {
            name: OdometryMeasurement(odo.dp, odo.dtheta, w_p, w_R) for name, odo in step.odometry.items()
        }
        out.append(StepMeasurements(step.t, visual, odometry, stray, self_seen, step.config))
    return out


def odometry_rotation(dtheta: float) -> np.ndarray:
    """The 2x2 free part of the odometry rotation R̂ (eq. (16))."""
    return rot2(dtheta)
