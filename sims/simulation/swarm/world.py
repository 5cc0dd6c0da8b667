"""Ground truth of Kanovsky's swarm: unicycle robots in a square arena, their cameras and odometry.

The world is stepped online (the PettingZoo env feeds actions one step at a time). A robot's state
is ``(x, y, theta)`` of its root horizontal frame in the world frame W (z up; the root is the node
centre, ``node_radius`` above the floor). Commands are unicycle ``(v, omega)`` held over a step and
integrated exactly (arcs); a robot that would leave the arena stops at the wall.

Sensing follows Kanovsky §3.1 -- a robot sees another inside the cone ``|angle| <= max_angle`` and
``distance <= max_distance`` -- through a pinhole camera, so each detection is a pixel circle
``(u, v, r)`` (Liu et al. 2024 eq. (1) inverted: ``r = f r_0 / z_c``) with Gaussian noise, tag drop-outs,
and occlusion by nearer robots. Every noise source (each robot's camera, odometry and wander policy)
has its own generator, keyed by the source's name, so adding a robot changes nobody else's noise.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np

from decentral.geometry import rot2, wrap_angle
from decentral.observations import Detection, Odometry
from sims.simulation.swarm.config import SwarmConfig

__all__ = ["SwarmWorld", "Sensing", "streams_for", "unicycle_step", "wander_actions"]


def streams_for(seed: int, names) -> dict[str, np.random.Generator]:
    """One generator per noise source, from ``SeedSequence(seed)`` keyed by a CRC-32 of its name."""
    root = np.random.SeedSequence(seed)
    return {
        n: np.random.default_rng(np.random.SeedSequence(root.entropy, spawn_key=(4, zlib.crc32(n.encode()))))
        for n in names
    }


def unicycle_step(state: np.ndarray, v: np.ndarray, omega: np.ndarray, dt: float) -> np.ndarray:
    """Exact unicycle motion over ``dt`` with constant ``(v, omega)``.

    Parameters
    ----------
    state : ndarray, shape (n, 3)
        ``(x, y, theta)`` per robot in W.
    v, omega : ndarray, shape (n,)

    Returns
    -------
    ndarray, shape (n, 3)
    """
    x, y, th = state.T
    dth = omega * dt
    small = np.abs(dth) < 1e-9
    safe = np.where(small, 1.0, omega)
    fx = np.where(small, v * dt * np.cos(th + dth / 2), v / safe * (np.sin(th + dth) - np.sin(th)))
    fy = np.where(small, v * dt * np.sin(th + dth / 2), -v / safe * (np.cos(th + dth) - np.cos(th)))
    return np.column_stack([x + fx, y + fy, wrap_angle(th + dth)])


@dataclass(frozen=True)
class Sensing:
    """What every robot's sensors report at one step.

    Attributes
    ----------
    odometry : dict[str, Odometry]
        Per robot, its noisy motion since the previous step (absent at step 0).
    true_motion : dict[str, ndarray]
        Per robot, the true ``(dx, dy, dtheta)`` (evaluation only).
    detections : dict[str, tuple[Detection, ...]]
        Per camera key ``"Ri/cam0"``, identified circles.
    visible : dict[str, tuple[str, ...]]
        Per robot, the robots truly in its field of view (evaluation only).
    """

    odometry: dict
    true_motion: dict
    detections: dict
    visible: dict


class SwarmWorld:
    """The true swarm, stepped online.

    Parameters
    ----------
    config : SwarmConfig
    seed : int
        Entry point of the randomness: initial placement and per-source sensor streams.
    """

    def __init__(self, config: SwarmConfig, seed: int):
        self.config = config
        self.names = config.names
        self.streams = streams_for(
            seed,
            ["placement"] + [f"{n}/cam0" for n in self.names] + [f"odometry/{n}" for n in self.names]
            + [f"policy/{n}" for n in self.names],
        )
        self.state = self._place(self.streams["placement"])
        self.k = 0
        self.t = 0.0

    def _place(self, rng: np.random.Generator) -> np.ndarray:
        """Random start poses, at least 4 node radii apart and 0.3 m from the walls."""
        c = self.config
        margin = min(0.3, c.arena / 4)
        out = []
        for _ in range(c.n_robots):
            for _attempt in range(1000):
                p = rng.uniform(margin, c.arena - margin, 2)
                if all(np.hypot(*(p - q[:2])) > 4 * c.node_radius for q in out):
                    break
            out.append(np.array([p[0], p[1], rng.uniform(-np.pi, np.pi)]))
        return np.array(out)

    def step(self, actions: np.ndarray) -> np.ndarray:
        """Apply commands ``actions`` (n, 2) = (v, omega), clipped to the limits; return true motions (n, 3)."""
        c = self.config
        a = np.asarray(actions, dtype=float).reshape(c.n_robots, 2)
        v = np.clip(a[:, 0], -c.max_speed, c.max_speed)
        w = np.clip(a[:, 1], -c.max_yaw_rate, c.max_yaw_rate)
        new = unicycle_step(self.state, v, w, c.dt)
        lo, hi = c.node_radius, c.arena - c.node_radius
        blocked = np.any((new[:, :2] < lo) | (new[:, :2] > hi), axis=1)
        new[blocked, :2] = self.state[blocked, :2]  # hits the wall: turns in place
        motion = np.zeros_like(new)
        for i in range(c.n_robots):
            d = new[i, :2] - self.state[i, :2]
            motion[i, :2] = rot2(self.state[i, 2]).T @ d  # Liu et al. 2024 eq. (6): in the previous root frame
            motion[i, 2] = wrap_angle(new[i, 2] - self.state[i, 2])
        self.state = new
        self.k += 1
        self.t = self.k * c.dt
        return motion

    def relative(self, i: int, j: int) -> np.ndarray:
        """True pose ``(x, y, theta)`` of robot j's root in robot i's root frame."""
        d = self.state[j, :2] - self.state[i, :2]
        xy = rot2(self.state[i, 2]).T @ d
        return np.array([xy[0], xy[1], float(wrap_angle(self.state[j, 2] - self.state[i, 2]))])

    def sense(self, motion: np.ndarray | None) -> Sensing:
        """Sensor readings at the current step; ``motion`` (n, 3) is the last true motion (``None`` at step 0)."""
        c = self.config
        odometry, true_motion = {}, {}
        if motion is not None:
            for i, n in enumerate(self.names):
                rng = self.streams[f"odometry/{n}"]
                z = rng.standard_normal(3)
                std = np.sqrt(np.diag(c.odometry_cov(motion[i])))
                noisy = motion[i] + std * z
                odometry[n] = Odometry(np.array([noisy[0], noisy[1], 0.0]), float(noisy[2]))
                true_motion[n] = motion[i].copy()
        detections, visible = {}, {}
        K = c.K
        cam = c.cam_in_root()
        f = 0.5 * (K[0, 0] + K[1, 1])
        half = np.radians(c.max_angle_deg)
        # every robot's position in every robot's root frame at once: rel[i, j] = R_i^T (p_j - p_i)
        cs, sn = np.cos(self.state[:, 2]), np.sin(self.state[:, 2])
        d = self.state[None, :, :2] - self.state[:, None, :2]  # (n, n, 2)
        rel_x = cs[:, None] * d[..., 0] + sn[:, None] * d[..., 1]
        rel_y = -sn[:, None] * d[..., 0] + cs[:, None] * d[..., 1]
        pcs = (np.stack([rel_x, rel_y, np.zeros_like(rel_x)], -1) - cam.p) @ cam.R  # (n, n, 3): R^T (x - p)
        for i, n in enumerate(self.names):
            rng = self.streams[f"{n}/cam0"]
            cands = []
            ahead = (pcs[i, :, 2] > 0.05) & (np.hypot(rel_x[i], rel_y[i]) <= c.max_distance)
            for j in map(int, np.flatnonzero(ahead)):
                if j == i:
                    continue
                dist = float(np.hypot(rel_x[i, j], rel_y[i, j]))
                pc = pcs[i, j]
                angle = float(np.arctan2(pc[0], pc[2]))
                u = K[0, 0] * pc[0] / pc[2] + K[0, 2]
                v = K[1, 1] * pc[1] / pc[2] + K[1, 2]
                r = f * c.node_radius / pc[2]
                inside = (r - 1e-9 <= u <= c.image_width - r + 1e-9) and (r <= v <= c.image_height - r)
                if dist <= c.max_distance and abs(angle) <= half and r >= c.min_radius_px and inside:
                    cands.append((pc[2], j, np.array([u, v, r])))
            cands.sort(key=lambda x: x[0])
            seen, kept = [], []
            for depth, j, uvr in cands:
                # occluded when a nearer robot's circle covers this circle's centre
                if any(np.hypot(*(uvr[:2] - o[:2])) < o[2] for o in kept):
                    continue
                kept.append(uvr)
                seen.append((j, uvr))
            # fixed draws per candidate so one robot's drop-out does not shift the rest of the stream
            z = rng.standard_normal((c.n_robots, 3))
            drop = rng.random(c.n_robots) < c.dropout
            dets = []
            for j, uvr in seen:
                if drop[j]:
                    continue
                noisy = uvr + z[j] * np.array([c.pixel_sigma, c.pixel_sigma, c.radius_sigma])
                noisy[2] = max(noisy[2], 0.5)
                dets.append(Detection(j, float(noisy[0]), float(noisy[1]), float(noisy[2])))
            detections[f"{n}/cam0"] = tuple(dets)
            visible[n] = tuple(self.names[j] for j, _ in seen)
        return Sensing(odometry, true_motion, detections, visible)


def wander_actions(world: SwarmWorld, rng_by_name: dict[str, np.random.Generator] | None = None) -> np.ndarray:
    """A simple exploration policy: cruise at 70 % speed with random turns, and turn away from walls.

    Returns
    -------
    ndarray, shape (n, 2)
        ``(v, omega)`` per robot.
    """
    c = world.config
    streams = rng_by_name or world.streams
    out = np.zeros((c.n_robots, 2))
    centre = np.array([c.arena / 2, c.arena / 2])
    for i, n in enumerate(world.names):
        rng = streams[f"policy/{n}"]
        x, y, th = world.state[i]
        turn = rng.normal(0.0, 0.5 * c.max_yaw_rate)
        margin = 0.6
        if min(x, y, c.arena - x, c.arena - y) < margin:
            want = np.arctan2(centre[1] - y, centre[0] - x)
            turn = 2.0 * float(wrap_angle(want - th)) / max(c.dt * 5, 1e-9)
        out[i] = (0.7 * c.max_speed, np.clip(turn, -c.max_yaw_rate, c.max_yaw_rate))
    return out
