"""Simulated sensors: odometry with noise and identified node detections from the pinhole model.

The noiseless detection of a visible node is Liu et al. 2024 eq. (1) inverted (see :mod:`sims.simulation.world.camera`);
noise, drop-outs, stray tags and wrong ids are then applied per :class:`SensorNoise`. Every noise
source (each assembly's odometry, each camera) draws from its own generator, made by
:func:`sensor_streams` from the run's seed and the source's name, so adding a robot does not change
another robot's noise.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, fields, replace

import numpy as np

from decentral.observations import Detection, Odometry
from sims.simulation.world.camera import covered_fraction, project_nodes, visible_mask
from decentral.geometry import wrap_angle
from sims.simulation.world.world import World

__all__ = ["SensorNoise", "sensor_streams", "odometry_at", "detections_at"]

#: node ids of stray tags (tags that belong to no assembly) start here
STRAY_ID_BASE = 9000


@dataclass(frozen=True)
class SensorNoise:
    """Noise and failure model of the sensors (defaults: realistic, Liu et al. 2024 §V-like).

    Attributes
    ----------
    pixel_sigma : float
        Std of the circle centre (u, v) noise [px].
    radius_sigma : float
        Std of the circle radius noise [px].
    dropout : float
        Probability that a visible node is not detected in a frame.
    odom_frac : float
        Std of odometry translation noise per component, as a fraction of the step's travel.
    odom_floor : float
        Std [m] added to the translation noise of a moving root.
    yaw_frac : float
        Std of odometry yaw noise as a fraction of the step's turn.
    yaw_per_metre : float
        Std [rad/m] of odometry yaw noise per metre travelled.
    yaw_floor : float
        Std [rad] added to the yaw noise of a moving root.
    odom_missing : float
        Probability that an assembly's odometry is missing at a step.
    stray_rate : float
        Expected stray tag detections (ids in no assembly) per frame.
    wrong_id : float
        Probability that a detection carries the id of another node of the same step.
    occlusion : bool
        Hide nodes whose circle is covered by nearer nodes' circles beyond ``occlusion_hide``.
    occlusion_hide : float
        Covered fraction from which a node is not detected.
    occluded_noise_gain : float
        A partly covered node's noise std is scaled by ``1 + gain * covered``.
    """

    pixel_sigma: float = 0.7
    radius_sigma: float = 0.5
    dropout: float = 0.05
    odom_frac: float = 0.03
    odom_floor: float = 0.0005
    yaw_frac: float = 0.03
    yaw_per_metre: float = 0.02
    yaw_floor: float = 0.001
    odom_missing: float = 0.02
    stray_rate: float = 0.0
    wrong_id: float = 0.0
    occlusion: bool = True
    occlusion_hide: float = 0.5
    occluded_noise_gain: float = 3.0

    def __post_init__(self):
        for f in fields(self):
            value = getattr(self, f.name)
            if f.type in ("float", float) and not (np.isfinite(value) and value >= 0):
                raise ValueError(f"{f.name} must be a finite non-negative number, got {value!r}")
        for name in ("dropout", "odom_missing", "wrong_id", "occlusion_hide"):
            if getattr(self, name) > 1:
                raise ValueError(f"{name} is a probability or fraction, got {getattr(self, name)!r}")

    @classmethod
    def none(cls, *, occlusion: bool = True) -> "SensorNoise":
        """Noiseless sensors: exact detections and odometry, no drop-outs, no outliers."""
        zero = {f.name: 0.0 for f in fields(cls) if f.type in ("float", float)}
        zero.update(occlusion=occlusion, occlusion_hide=cls.occlusion_hide)
        return cls(**zero)

    def without_noise(self) -> "SensorNoise":
        """This model with every noise and failure switched off (occlusion geometry kept)."""
        return replace(SensorNoise.none(occlusion=self.occlusion), occlusion_hide=self.occlusion_hide)


def sensor_streams(seed: int, names) -> dict[str, np.random.Generator]:
    """One generator per noise source, keyed by the source's name.

    Each stream is a child of ``SeedSequence(seed)`` whose spawn key is a CRC-32 of the name, so a
    source's stream depends only on the seed and its own name.
    """
    root = np.random.SeedSequence(seed)
    out = {}
    for name in names:
        child = np.random.SeedSequence(root.entropy, spawn_key=(1, zlib.crc32(name.encode("utf-8"))))
        out[name] = np.random.default_rng(child)
    return out


def odometry_at(world: World, name: str, k: int, noise: SensorNoise, rng: np.random.Generator) -> Odometry | None:
    """Odometry of assembly ``name`` at step ``k >= 1`` (``None`` when it is missing).

    The true values are the root's motion since step k-1 written in the root frame at k-1
    (Liu et al. 2024 eq. (6)): ``dp = R_{k-1}^T (p_k - p_{k-1})``, ``dtheta = yaw_k - yaw_{k-1}``.
    """
    a = world.assembly(name)
    prev, cur = a.root_pose(k - 1, world.node_radius), a.root_pose(k, world.node_radius)
    dp = prev.R.T @ (cur.p - prev.p)
    dtheta = float(wrap_angle(a.yaw[k] - a.yaw[k - 1]))
    # draw every variate whatever happens, so one failure does not shift the rest of the stream
    missing = rng.random() < noise.odom_missing
    z_p, z_t = rng.standard_normal(2), rng.standard_normal()
    travel = float(np.hypot(dp[0], dp[1]))
    moving = travel > 1e-9 or abs(dtheta) > 1e-9
    sp = noise.odom_frac * travel + (noise.odom_floor if moving else 0.0)
    st = noise.yaw_frac * abs(dtheta) + noise.yaw_per_metre * travel + (noise.yaw_floor if moving else 0.0)
    if missing:
        return None
    noisy = dp.copy()
    noisy[:2] += sp * z_p
    return Odometry(noisy, dtheta + st * float(z_t))


def detections_at(world: World, k: int, noise: SensorNoise, streams: dict[str, np.random.Generator]):
    """Every camera's detections at step ``k`` and the truth of what it sees.

    Parameters
    ----------
    streams : dict
        Camera key -> generator (from :func:`sensor_streams`).

    Returns
    -------
    detections : dict[str, tuple[Detection, ...]]
        Camera key -> identified detections, as the log carries them.
    visible : dict[str, list[dict]]
        Camera key -> the nodes in view with their noiseless circle and covered fraction.
    """
    ids, owners, centres = world.nodes_in_world(k)
    owners = np.asarray(owners)
    detections, visible = {}, {}
    for rig in world.cameras:
        rng = streams[rig.key]
        uvr, depth = project_nodes(rig.spec.K, world.camera_in_world(rig, k), centres, world.node_radius)
        seen = visible_mask(rig.spec, uvr, depth) & (owners != rig.assembly)
        covered = covered_fraction(uvr, depth, targets=seen) if noise.occlusion else np.zeros(len(ids))
        if noise.occlusion:
            seen &= covered < noise.occlusion_hide
        idx = np.flatnonzero(seen)
        visible[rig.key] = [
            {"id": int(ids[i]), "u": float(uvr[i, 0]), "v": float(uvr[i, 1]), "r": float(uvr[i, 2]),
             "covered": float(covered[i])}
            for i in idx
        ]
        n = len(idx)
        drop = rng.random(n) < noise.dropout
        z = rng.standard_normal((n, 3))
        wrong = rng.random(n) < noise.wrong_id
        wrong_pick = rng.integers(0, max(len(ids) - 1, 1), n)
        scale = 1.0 + noise.occluded_noise_gain * covered[idx]
        dets = []
        for j, i in enumerate(idx):
            if drop[j]:
                continue
            u = uvr[i, 0] + noise.pixel_sigma * scale[j] * z[j, 0]
            v = uvr[i, 1] + noise.pixel_sigma * scale[j] * z[j, 1]
            r = max(uvr[i, 2] + noise.radius_sigma * scale[j] * z[j, 2], 1.0)
            node = int(ids[i])
            if wrong[j] and len(ids) > 1:
                others = np.delete(ids, i)
                node = int(others[wrong_pick[j] % len(others)])
            dets.append(Detection(node, float(u), float(v), float(r)))
        n_stray = rng.poisson(noise.stray_rate) if noise.stray_rate > 0 else 0
        for s in range(n_stray):
            r = float(rng.uniform(8.0, 40.0))
            u = float(rng.uniform(r, rig.spec.width - r))
            v = float(rng.uniform(r, rig.spec.height - r))
            stray = STRAY_ID_BASE + int(rng.integers(0, 500))
            if stray not in ids:
                dets.append(Detection(stray, u, v, r))
        detections[rig.key] = tuple(dets)
    return detections, visible
