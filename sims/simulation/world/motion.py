"""Smooth planar root trajectories: unicycle wandering, smooth jitter, and standing still.

Each function returns ``(xy, yaw)``: ``xy`` (T, 2) root positions in the world floor plane [m] and
``yaw`` (T,) root headings [rad, unwrapped], sampled every ``dt`` seconds. Heights come from the
floor an assembly stands on, not from here.
"""

from __future__ import annotations

import numpy as np

__all__ = ["still", "jitter", "wander_many"]


def still(steps: int, xy0, yaw0: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """A root that never moves: ``steps`` copies of ``xy0`` (2,) and ``yaw0``."""
    return np.tile(np.asarray(xy0, dtype=float), (steps, 1)), np.full(steps, float(yaw0))


def jitter(
    steps: int,
    dt: float,
    xy0,
    yaw0: float,
    rng: np.random.Generator,
    *,
    amplitude: float = 0.15,
    yaw_amplitude: float = 0.15,
    period: float = 12.0,
    n_terms: int = 3,
) -> tuple[np.ndarray, np.ndarray]:
    """Smooth random motion around ``xy0``: a sum of ``n_terms`` sinusoids per coordinate.

    Position stays within ``amplitude`` [m] of ``xy0`` and yaw within ``yaw_amplitude`` [rad] of
    ``yaw0``; the slowest term has period ``period`` [s], the others are faster harmonics with random
    phases, so the path is smooth (infinitely differentiable) but not periodic-looking.
    """
    t = np.arange(steps) * dt
    out = []
    for amp in (amplitude, amplitude, yaw_amplitude):
        w = rng.uniform(0.5, 1.0, n_terms)
        w = w / w.sum()
        freq = 2 * np.pi / period * np.arange(1, n_terms + 1) * rng.uniform(0.8, 1.25, n_terms)
        phase = rng.uniform(0, 2 * np.pi, n_terms)
        wave = (w[None] * (np.sin(freq[None] * t[:, None] + phase[None]) - np.sin(phase[None]))).sum(axis=1)
        out.append(amp * wave / 2.0)
    xy = np.asarray(xy0, dtype=float)[None] + np.column_stack(out[:2])
    return xy, float(yaw0) + out[2]


def wander_many(
    steps: int,
    dt: float,
    starts,
    homes,
    rng: np.random.Generator,
    *,
    speed: float = 0.12,
    radius: float = 0.4,
    clearance: float = 0.8,
    curvature_sigma: float = 1.5,
    curvature_tau: float = 2.0,
    max_curvature: float = 4.0,
    substeps: int = 10,
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Unicycle roots with smooth random curvature, kept near their homes and apart from each other.

    Each root drives at ``speed`` [m/s]; its curvature is an Ornstein-Uhlenbeck process (stationary
    std ``curvature_sigma`` [1/m], correlation time ``curvature_tau`` [s]) plus a steering term
    towards its home once it is farther than ``radius`` from it, and away from any other root closer
    than ``clearance``. Integrated with ``substeps`` Euler sub-steps per ``dt``, so heading is smooth.

    Parameters
    ----------
    starts : sequence of (x, y, yaw)
        Initial root poses in the world plane.
    homes : sequence of (x, y)
        Centres the roots wander around.

    Returns
    -------
    list of (xy (T, 2), yaw (T,)), one per root.
    """
    n = len(starts)
    state = np.asarray(starts, dtype=float).reshape(n, 3).copy()
    homes = np.asarray(homes, dtype=float).reshape(n, 2)
    kappa = np.zeros(n)
    h = dt / substeps
    decay = np.exp(-h / curvature_tau)
    kick = curvature_sigma * np.sqrt(1.0 - decay**2)
    xy = np.zeros((steps, n, 2))
    yaw = np.zeros((steps, n))
    for k in range(steps):
        xy[k], yaw[k] = state[:, :2], state[:, 2]
        for _ in range(substeps):
            kappa = decay * kappa + kick * rng.standard_normal(n)
            steer = np.zeros(n)
            to_home = homes - state[:, :2]
            far = np.linalg.norm(to_home, axis=1)
            want = np.arctan2(to_home[:, 1], to_home[:, 0])
            err = (want - state[:, 2] + np.pi) % (2 * np.pi) - np.pi
            steer += 3.0 * err * np.clip((far - radius) / radius, 0.0, 1.0)
            for i in range(n):
                d = state[:, :2] - state[i, :2]
                dist = np.linalg.norm(d, axis=1)
                dist[i] = np.inf
                j = int(np.argmin(dist))
                if dist[j] < clearance:
                    away = np.arctan2(-d[j, 1], -d[j, 0])
                    e = (away - state[i, 2] + np.pi) % (2 * np.pi) - np.pi
                    steer[i] += 4.0 * e * (1.0 - dist[j] / clearance)
            curv = np.clip(kappa + steer, -max_curvature, max_curvature)
            state[:, 0] += speed * h * np.cos(state[:, 2])
            state[:, 1] += speed * h * np.sin(state[:, 2])
            state[:, 2] += speed * h * curv
    return [(xy[:, i].copy(), yaw[:, i].copy()) for i in range(n)]
