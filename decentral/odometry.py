"""Odometry trajectories to the log's per-step odometry: pose interpolation and increments.

A robot records its odometry as a trajectory: poses ``(p, yaw)`` of its root horizontal frame in an
odometry frame O at its own sample times. The log needs, per step k, the root's motion since step
k-1 written in the root frame at k-1 (Liu et al. 2024 §II; contract ``steps[k].odometry``):

.. math:: dp_k = R_z(\\psi_{k-1})^T (p_k - p_{k-1}), \\qquad d\\theta_k = \\mathrm{wrap}(\\psi_k - \\psi_{k-1}),

with the poses at the step times obtained by interpolating the trajectory: linear in position, along
the shorter arc in yaw.
"""

from __future__ import annotations

import numpy as np

from decentral.geometry import wrap_angle

__all__ = ["interpolate_planar", "increments"]


def interpolate_planar(t: np.ndarray, p: np.ndarray, yaw: np.ndarray, t_query: np.ndarray,
                       tolerance: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Poses of a sampled planar trajectory at query times, where a sample is close enough.

    Parameters
    ----------
    t : ndarray, shape (T,)
        Sample times [s], strictly increasing.
    p : ndarray, shape (T, 3)
        Positions in the odometry frame [m].
    yaw : ndarray, shape (T,)
        Yaws about the odometry frame's z axis [rad].
    t_query : ndarray, shape (Q,)
        Times at which the pose is wanted [s].
    tolerance : float
        A query is answered only if a sample lies within ``tolerance`` seconds of it; between the
        two samples around it the pose is interpolated (linear position, shortest-arc yaw); within
        ``tolerance`` beyond either end the end pose is held.

    Returns
    -------
    p_q : ndarray, shape (Q, 3)
    yaw_q : ndarray, shape (Q,)
        Interpolated poses (rows where ``ok`` is false are zeros, never used).
    ok : ndarray of bool, shape (Q,)
        Whether the query had a sample within ``tolerance``.
    """
    t, t_query = np.asarray(t, float), np.asarray(t_query, float)
    p, yaw = np.asarray(p, float).reshape(-1, 3), np.asarray(yaw, float)
    q = len(t_query)
    p_q, yaw_q, ok = np.zeros((q, 3)), np.zeros(q), np.zeros(q, bool)
    if len(t) == 0:
        return p_q, yaw_q, ok
    hi = np.clip(np.searchsorted(t, t_query), 1, max(len(t) - 1, 1))
    lo = hi - 1 if len(t) > 1 else np.zeros_like(hi)
    hi = np.minimum(hi, len(t) - 1)
    nearest = np.minimum(np.abs(t_query - t[lo]), np.abs(t[hi] - t_query))
    ok = nearest <= tolerance
    span = t[hi] - t[lo]
    s = np.where(span > 0, (t_query - t[lo]) / np.where(span > 0, span, 1.0), 0.0)
    s = np.clip(s, 0.0, 1.0)[:, None]  # hold the end pose outside the samples
    p_q = (1 - s) * p[lo] + s * p[hi]
    yaw_q = np.asarray(wrap_angle(yaw[lo] + s[:, 0] * wrap_angle(yaw[hi] - yaw[lo])))
    p_q[~ok], yaw_q[~ok] = 0.0, 0.0
    return p_q, yaw_q, ok


def increments(p: np.ndarray, yaw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-step motion ``(dp, dtheta)`` of consecutive poses, in the root frame at the earlier step.

    Parameters
    ----------
    p : ndarray, shape (K, 3)
        Root positions in the odometry frame at the steps.
    yaw : ndarray, shape (K,)
        Root yaws at the steps.

    Returns
    -------
    dp : ndarray, shape (K-1, 3)
        ``R_z(yaw[k-1])^T (p[k] - p[k-1])`` for k = 1..K-1.
    dtheta : ndarray, shape (K-1,)
        ``wrap(yaw[k] - yaw[k-1])``.
    """
    p, yaw = np.asarray(p, float).reshape(-1, 3), np.asarray(yaw, float)
    d = np.diff(p, axis=0)
    c, s = np.cos(yaw[:-1]), np.sin(yaw[:-1])
    dp = np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], d[:, 2]], axis=1)
    return dp, np.asarray(wrap_angle(np.diff(yaw)))
