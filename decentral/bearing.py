"""Bearing-only baseline (Liu et al. 2024 §V-C 2, after Wang et al. [1]_): bearings plus odometry, no radius.

For the reference observer ``o`` and each target ``a``, odometry is integrated over the window into
each one's start-of-window frame (taken as exact, as [1]_ does), leaving one unknown: the planar
pose ``(alpha, tau)`` of ``a``'s start frame in ``o``'s. A node ``n`` of ``a`` at step ``k`` then
sits at ``R(alpha) x_k + tau`` with ``x_k`` known, and each bearing ``b_k`` seen from camera centre
``c_k`` gives the residual

.. math:: e_k = (I - b_k b_k^T) (R(\\alpha) x_k + \\tau - c_k),

linear in ``(cos alpha, sin alpha, tau)``. ``tau`` is eliminated in closed form and ``alpha``
minimized globally on the circle (a dense grid refined by Newton), which is exact for this
one-rotation problem. Only the target's root node is used by default, as in the paper's baseline.

References
----------
.. [1] Y. Wang, X. Wen, F. Gao, "Certifiable mutual localization and trajectory planning for
   bearing-based robot swarm", arXiv:2401.07784, 2024.
"""

from __future__ import annotations

import time
from typing import Callable
from dataclasses import dataclass, field

import numpy as np

from decentral.errors import InputError
from decentral.factors import NoiseModel, StepMeasurements, measure_log
from decentral.geometry import rotz, wrap_angle
from decentral.observations import Estimate, EstimateStep, ObservationLog, PlanarPose, require_log, resolve_reference
from decentral.unplaced import count_reasons

__all__ = ["BearingConfig", "estimate_log_bearing", "solve_bearing_window"]


@dataclass(frozen=True)
class BearingConfig:
    """``window`` steps per solve; ``nodes`` is ``"root"`` (the paper's baseline) or ``"all"``."""

    window: int = 5
    nodes: str = "root"
    noise: NoiseModel = field(default_factory=NoiseModel)

    def __post_init__(self) -> None:
        if self.nodes not in ("root", "all"):
            raise InputError(f"nodes must be 'root' or 'all', got {self.nodes!r}", field="nodes")
        if not (isinstance(self.window, int) and self.window >= 1):
            raise InputError(f"window must be an integer >= 1, got {self.window!r}", field="window")


def _dead_reckon(measurements: list[StepMeasurements], name: str, span: range):
    """Yaw (K,) and position (K, 3) of ``name`` at each step of ``span`` in its frame at span[0]."""
    yaw, pos = [0.0], [np.zeros(3)]
    for k in span[1:]:
        odo = measurements[k].odometry[name]
        pos.append(pos[-1] + rotz(yaw[-1]) @ odo.dp)
        yaw.append(yaw[-1] + odo.dtheta)
    return np.array(yaw), np.array(pos)


def _odometry_span(measurements, names, k, window) -> range:
    """The longest span ending at ``k`` (at most ``window`` steps) with odometry for all ``names``."""
    start, lowest = k, max(0, k - window + 1)
    while start > lowest and all(n in measurements[start].odometry for n in names):
        start -= 1
    return range(start, k + 1)


def solve_bearing_window(x: np.ndarray, c: np.ndarray, b: np.ndarray) -> tuple[float, np.ndarray] | None:
    """Minimize ``sum_k |(I - b_k b_k^T)(R(alpha) x_k + tau - c_k)|^2`` over alpha, tau.

    Parameters
    ----------
    x : ndarray, shape (n, 3)
        Node positions in the target's start frame.
    c, b : ndarray, shape (n, 3)
        Camera centres and unit bearings in the observer's start frame.

    Returns
    -------
    (alpha, tau) or None when the bearings do not determine the pose (too few or all parallel).
    """
    P = np.eye(3)[None] - b[:, :, None] * b[:, None, :]  # (n, 3, 3)
    # residual = P (alpha_c * A1 x + alpha_s * A2 x + x_z e_z + tau - c)
    Rx_c = np.column_stack([x[:, 0], x[:, 1], np.zeros(len(x))])
    Rx_s = np.column_stack([-x[:, 1], x[:, 0], np.zeros(len(x))])
    const = np.column_stack([np.zeros(len(x)), np.zeros(len(x)), x[:, 2]]) - c
    Acs = np.stack([np.einsum("nij,nj->ni", P, Rx_c), np.einsum("nij,nj->ni", P, Rx_s)], -1).reshape(-1, 2)
    At = P.reshape(-1, 3)
    y = -np.einsum("nij,nj->ni", P, const).reshape(-1)
    AtA = At.T @ At
    ev = np.linalg.eigvalsh(AtA)
    if ev[0] <= 1e-9 * max(ev[-1], 1e-300):
        return None  # depth along the bearing is not observable: all bearings parallel
    pinv = np.linalg.solve(AtA, At.T)
    proj = lambda M: M - At @ (pinv @ M)  # noqa: E731 — complement of range(At)
    B, yb = proj(Acs), proj(y[:, None])[:, 0]
    G, h = B.T @ B, B.T @ yb
    grid = np.linspace(-np.pi, np.pi, 721)[:-1]
    w = np.stack([np.cos(grid), np.sin(grid)], 1)
    cost = np.einsum("ki,ij,kj->k", w, G, w) - 2 * w @ h
    if cost.max() - cost.min() <= 1e-12 * max(abs(cost).max(), 1e-300):
        return None  # yaw not observable
    alpha = grid[np.argmin(cost)]
    for _ in range(20):  # Newton on the circle
        w, dw = np.array([np.cos(alpha), np.sin(alpha)]), np.array([-np.sin(alpha), np.cos(alpha)])
        g = 2 * dw @ G @ w - 2 * dw @ h
        hess = 2 * dw @ G @ dw - 2 * w @ G @ w + 2 * w @ h
        if hess <= 0 or abs(g) < 1e-14:
            break
        alpha -= g / hess
    w = np.array([np.cos(alpha), np.sin(alpha)])
    tau = pinv @ (y - Acs @ w)
    return float(alpha), tau


def estimate_log_bearing(log: ObservationLog, config: BearingConfig = BearingConfig(),
                         reference: str | None = None, progress: Callable[..., None] | None = None) -> Estimate:
    """Bearing-only estimates of every target the reference observes (Liu et al. 2024 §V-C 2).

    ``progress``, when given, is called after each step as ``progress(steps_done, steps_total)``.
    """
    log = require_log(log)
    if not isinstance(config, BearingConfig):
        raise InputError(f"expected a BearingConfig, got {type(config).__name__}", field="config")
    reference = resolve_reference(log, reference)
    start = time.perf_counter()
    measurements = measure_log(log, config.noise)
    steps = []
    targets = [a for a in log.assemblies if a != reference]
    for k in range(len(measurements)):
        poses, unplaced = {}, {}
        for target in targets:
            pose = _estimate_target(measurements, reference, target, k, config)
            if isinstance(pose, str):
                unplaced[target] = pose
            else:
                poses[target] = pose
        steps.append(EstimateStep(measurements[k].t, poses, unplaced))
        if progress is not None:
            progress(k + 1, len(measurements))
    stats = {"estimator": "bearing", "window": config.window, "nodes": config.nodes,
             "unplaced": count_reasons(step.unplaced for step in steps),
             "stray_detections": int(sum(m.stray for m in measurements)), "seconds": time.perf_counter() - start}
    return Estimate(reference, tuple(steps), stats)


def _estimate_target(measurements, reference, target, k, config) -> PlanarPose | str:
    """The target's pose at step ``k`` relative to the reference, or why there is none (a reason code of
    :data:`decentral.unplaced.REASONS`: no bearing of it, or bearings that do not determine it)."""
    span = _odometry_span(measurements, (reference, target), k, config.window)
    yaw_o, pos_o = _dead_reckon(measurements, reference, span)
    yaw_a, pos_a = _dead_reckon(measurements, target, span)
    xs, cs, bs = [], [], []
    for j, s in enumerate(span):
        vis = measurements[s].visual
        for i in range(len(vis)):
            if vis.observer[i] != reference or vis.target[i] != target:
                continue
            q = vis.q[i]
            if config.nodes == "root" and np.linalg.norm(q) > 1e-9:
                continue
            xs.append(pos_a[j] + rotz(yaw_a[j]) @ q)
            cs.append(pos_o[j] + rotz(yaw_o[j]) @ vis.origin[i])
            bs.append(rotz(yaw_o[j]) @ vis.bearing[i])
    if not xs:
        return "no_data"
    if len(xs) < 3:
        return "yaw_unobservable"  # two bearings fit (alpha, tau) exactly, with spurious solutions
    solved = solve_bearing_window(np.array(xs), np.array(cs), np.array(bs))
    if solved is None:
        return "yaw_unobservable"
    alpha, tau = solved
    # target root at the last step, in the observer's frame at the last step (Liu et al. 2024 eq. (19))
    p_world = rotz(alpha) @ pos_a[-1] + tau
    p_rel = rotz(yaw_o[-1]).T @ (p_world - pos_o[-1])
    return PlanarPose(p_rel, float(wrap_angle(alpha + yaw_a[-1] - yaw_o[-1])))
