"""Extended Kalman filtering of planar poses for one-node robots (Kanovsky's future work, §5).

A planar pose ``s = (x, y, theta)`` of frame B in frame A maps ``x_A = R(theta) x_B + (x, y)``
(docs/formats.md conventions, yaw about z). Composition and inverse:

.. math::

    a \\oplus b = (t_a + R(\\theta_a) t_b,\\; \\theta_a + \\theta_b), \\qquad
    \\ominus a = (-R(\\theta_a)^T t_a,\\; -\\theta_a).

Two filters are built from these, each a pure function over arrays:

* **Own motion** (:func:`predict_pose`): a robot's pose in the frame it started in, driven by its
  odometry ``u = (dx, dy, dtheta)``, the root's motion since the previous step written in the previous
  root frame (Liu et al. 2024 eq. (6)): :math:`x_k = x_{k-1} \\oplus u_k`.
* **Ego-centric tracks** (:func:`predict_relative`, :func:`update_detection`): robot i keeps, for each
  other robot j, the pose ``s`` of j's frame in i's *current* frame (Kanovsky §3: "each robot
  maintains ... its own position (assuming itself to be point 0, 0) with the relational data of every
  other robot"). When i moves by ``u``, :math:`s_k = \\ominus u_k \\oplus s_{k-1}` plus process noise
  for j's own (unknown) motion. Measurements are pixel circles ``(u, v, r)``: i's camera seeing j, or
  j's camera seeing i (shared over the network), through the pinhole model whose inverse is
  Liu et al. 2024 eq. (1): a node centre at depth ``z_c`` projects to ``r = f r_0 / z_c``.

A sphere looks the same from every side, so i's own detections of j fix only j's position; j's yaw
relative to i becomes observable from j's detections of i (mutual observation), and
:func:`yaw_from_mutual` gives its closed-form initial value. Estimates shared by peers are fused with
covariance intersection [1]_ (:func:`covariance_intersection`), which stays consistent whatever the
unknown correlation between the two estimates (peers' estimates partly derive from ours).

All angles are wrapped to [-pi, pi). Updates use the Joseph form and report the normalized
innovation squared (NIS) so callers can gate outliers (a wrong tag id).

References
----------
.. [1] S. J. Julier, J. K. Uhlmann, "A non-divergent estimation algorithm in the presence of
   unknown correlations", Proc. American Control Conference, 1997.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import eigh

from decentral.geometry import rot2, wrap_angle

__all__ = [
    "compose",
    "invert",
    "compose_jacobians",
    "invert_jacobian",
    "predict_pose",
    "predict_relative",
    "project_target",
    "UpdateResult",
    "update_detection",
    "yaw_from_mutual",
    "covariance_intersection",
    "nees",
]

_DR = np.array([[0.0, -1.0], [1.0, 0.0]])  # d R(theta) / d theta = R(theta) @ _DR


def compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Planar pose composition ``a ⊕ b`` (3,): pose of C in A from B in A (``a``) and C in B (``b``)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    t = a[:2] + rot2(a[2]) @ b[:2]
    return np.array([t[0], t[1], float(wrap_angle(a[2] + b[2]))])


def invert(a: np.ndarray) -> np.ndarray:
    """Planar pose inverse ``⊖a`` (3,): pose of A in B from B in A."""
    a = np.asarray(a, dtype=float)
    t = -rot2(a[2]).T @ a[:2]
    return np.array([t[0], t[1], float(wrap_angle(-a[2]))])


def compose_jacobians(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Jacobians (3, 3) of ``a ⊕ b`` with respect to ``a`` and to ``b``."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    R = rot2(a[2])
    Ja = np.eye(3)
    Ja[:2, 2] = R @ _DR @ b[:2]
    Jb = np.eye(3)
    Jb[:2, :2] = R
    return Ja, Jb


def invert_jacobian(a: np.ndarray) -> np.ndarray:
    """Jacobian (3, 3) of ``⊖a`` with respect to ``a``."""
    R = rot2(a[2])
    J = -np.eye(3)
    J[:2, :2] = -R.T
    J[:2, 2] = -(R @ _DR).T @ a[:2]
    return J


def _sym(P: np.ndarray) -> np.ndarray:
    return 0.5 * (P + P.T)


def predict_pose(mean: np.ndarray, cov: np.ndarray, odometry: np.ndarray, odometry_cov: np.ndarray):
    """Propagate a robot's own pose through one odometry step.

    .. math:: x_k = x_{k-1} \\oplus u_k, \\quad P_k = F P_{k-1} F^T + G U G^T

    with ``u`` the root's motion since k-1 in the root frame at k-1 (Liu et al. 2024 eq. (6)).

    Parameters
    ----------
    mean : ndarray, shape (3,)
        ``(x, y, theta)`` of the robot in its start frame at k-1 [m, m, rad].
    cov : ndarray, shape (3, 3)
    odometry : ndarray, shape (3,)
        ``(dx, dy, dtheta)``.
    odometry_cov : ndarray, shape (3, 3)
        Covariance of the odometry noise.

    Returns
    -------
    mean : ndarray, shape (3,)
    cov : ndarray, shape (3, 3)
    """
    F, G = compose_jacobians(mean, odometry)
    return compose(mean, odometry), _sym(F @ cov @ F.T + G @ odometry_cov @ G.T)


def predict_relative(
    mean: np.ndarray,
    cov: np.ndarray,
    odometry: np.ndarray,
    odometry_cov: np.ndarray,
    target_motion: np.ndarray | None = None,
    target_motion_cov: np.ndarray | None = None,
    process_cov: np.ndarray | None = None,
):
    """Move a track into the observer's new frame after both robots moved over one step.

    .. math:: s_k = \\ominus u_k \\oplus s_{k-1} \\oplus w_k, \\quad
              P_k = F P F^T + G U G^T + J W J^T + Q

    Parameters
    ----------
    mean : ndarray, shape (3,)
        Pose of the target in the observer's frame at k-1.
    cov : ndarray, shape (3, 3)
    odometry : ndarray, shape (3,)
        Observer's motion ``u`` (pose of its frame at k in its frame at k-1, Liu et al. 2024 eq. (6)).
    odometry_cov : ndarray, shape (3, 3)
    target_motion : ndarray, shape (3,), optional
        The target's own motion ``w`` over the step in its frame at k-1 (its shared odometry);
        zero when unknown, in which case ``target_motion_cov`` should cover its possible motion.
    target_motion_cov : ndarray, shape (3, 3), optional
        Covariance ``W`` of ``w`` (default zero).
    process_cov : ndarray, shape (3, 3), optional
        Extra additive noise ``Q`` in the new frame (default zero).

    Returns
    -------
    mean, cov : ndarray, shapes (3,), (3, 3)
    """
    odometry = np.asarray(odometry, dtype=float)
    inv_u = invert(odometry)
    J_inv = invert_jacobian(odometry)
    Ja, Jb = compose_jacobians(inv_u, mean)
    moved = compose(inv_u, mean)
    G = Ja @ J_inv
    P = Jb @ cov @ Jb.T + G @ odometry_cov @ G.T
    w = np.zeros(3) if target_motion is None else np.asarray(target_motion, dtype=float)
    Jm, Jw = compose_jacobians(moved, w)
    P = Jm @ P @ Jm.T
    if target_motion_cov is not None:
        P = P + Jw @ target_motion_cov @ Jw.T
    if process_cov is not None:
        P = P + process_cov
    return compose(moved, w), _sym(P)


def project_target(
    position: np.ndarray,
    K: np.ndarray,
    cam_R: np.ndarray,
    cam_p: np.ndarray,
    node_radius: float,
) -> tuple[np.ndarray, np.ndarray, float]:
    """Pixel circle of a node centred at ``(x, y, 0)`` in the camera's root frame, and its Jacobian.

    ``(u, v)`` is the pinhole projection and ``r = f r_0 / z_c`` (Liu et al. 2024 eq. (1) inverted).

    Parameters
    ----------
    position : ndarray, shape (2,)
        Node centre ``(x, y)`` in the root horizontal frame (same height as the root centre).
    K : ndarray, shape (3, 3)
    cam_R, cam_p : ndarray, shapes (3, 3), (3,)
        Pose of the camera (OpenCV axes) in the root frame.
    node_radius : float

    Returns
    -------
    uvr : ndarray, shape (3,)
    H : ndarray, shape (3, 2)
        ``d uvr / d position``.
    depth : float
        ``z_c``; the projection is meaningless when it is not positive.
    """
    x = np.array([position[0], position[1], 0.0])
    pc = cam_R.T @ (x - cam_p)
    z = float(pc[2])
    zs = z if abs(z) > 1e-9 else 1e-9
    f = 0.5 * (K[0, 0] + K[1, 1])
    uvr = np.array([K[0, 0] * pc[0] / zs + K[0, 2], K[1, 1] * pc[1] / zs + K[1, 2], f * node_radius / zs])
    d_pc = np.array([
        [K[0, 0] / zs, 0.0, -K[0, 0] * pc[0] / zs**2],
        [0.0, K[1, 1] / zs, -K[1, 1] * pc[1] / zs**2],
        [0.0, 0.0, -f * node_radius / zs**2],
    ])
    H = d_pc @ cam_R.T[:, :2]
    return uvr, H, z


@dataclass(frozen=True)
class UpdateResult:
    """Outcome of one measurement update.

    Attributes
    ----------
    mean : ndarray, shape (3,)
    cov : ndarray, shape (3, 3)
    nis : float
        Normalized innovation squared of the measurement against the prior.
    accepted : bool
        False when the NIS exceeded the gate or the target was behind the camera; then ``mean`` and
        ``cov`` are the prior unchanged.
    """

    mean: np.ndarray
    cov: np.ndarray
    nis: float
    accepted: bool


def update_detection(
    mean: np.ndarray,
    cov: np.ndarray,
    uvr: np.ndarray,
    uvr_cov: np.ndarray,
    K: np.ndarray,
    cam_R: np.ndarray,
    cam_p: np.ndarray,
    node_radius: float,
    *,
    mutual: bool = False,
    gate: float = np.inf,
    iterations: int = 5,
) -> UpdateResult:
    """EKF update of a track ``s`` (target's pose in the observer's frame) with one pixel circle.

    With ``mutual=False`` the observer's camera saw the target: the node centre in the camera's root
    frame is ``s[:2]``. With ``mutual=True`` the *target's* camera saw the observer (a detection the
    target shared): the centre in the target's root frame is ``(⊖s)[:2] = -R(theta)^T s[:2]``, which
    makes ``theta`` observable.

    Parameters
    ----------
    mean, cov : ndarray, shapes (3,), (3, 3)
        Prior of ``s``.
    uvr : ndarray, shape (3,)
        Measured circle [px].
    uvr_cov : ndarray, shape (3, 3)
        Its noise covariance [px^2].
    K, cam_R, cam_p, node_radius
        The measuring camera (see :func:`project_target`).
    mutual : bool
    gate : float
        Largest NIS accepted (e.g. ``scipy.stats.chi2.ppf(0.999, 3)``), tested at the prior.
    iterations : int
        Iterated-EKF relinearizations (1 = the plain EKF update).
    """
    prior = np.asarray(mean, dtype=float)
    z = np.asarray(uvr, dtype=float)
    x = prior.copy()
    nis = float("inf")
    for it in range(max(int(iterations), 1)):
        # iterated EKF (Gauss-Newton on the MAP cost): relinearize at the current iterate, which
        # matters at close range where the pinhole model bends within the prior's spread
        if mutual:
            pos = invert(x)[:2]
            J = invert_jacobian(x)[:2, :]
        else:
            pos = x[:2]
            J = np.eye(3)[:2, :]
        pred, H_pos, depth = project_target(pos, K, cam_R, cam_p, node_radius)
        if depth <= 1e-6:
            return UpdateResult(prior, cov, float("inf"), False)
        H = H_pos @ J
        S = _sym(H @ cov @ H.T + uvr_cov)
        dx = prior - x
        dx[2] = wrap_angle(dx[2])
        innov = z - pred - H @ dx  # z - h(x_i) - H_i (x_0 - x_i)
        try:
            gain = np.linalg.solve(S, H @ cov).T
        except np.linalg.LinAlgError:
            return UpdateResult(prior, cov, float("inf"), False)
        if it == 0:
            nis = float(innov @ np.linalg.solve(S, innov))
            if not np.isfinite(nis) or nis > gate:
                return UpdateResult(prior, cov, nis, False)
        new = prior + gain @ innov
        new[2] = wrap_angle(new[2])
        step = new - x
        step[2] = wrap_angle(step[2])
        x = new
        if np.max(np.abs(step)) < 1e-10:
            break
    IKH = np.eye(3) - gain @ H
    P = IKH @ cov @ IKH.T + gain @ uvr_cov @ gain.T  # Joseph form
    return UpdateResult(x, _sym(P), nis, True)


def yaw_from_mutual(target_in_observer: np.ndarray, observer_in_target: np.ndarray) -> float:
    """Relative yaw of the target from both robots' views of each other.

    If ``t = s[:2]`` is the target's position in the observer's frame and ``b`` the observer's
    position in the target's frame, then ``R(theta) b = -t``, so
    ``theta = atan2(-t_y, -t_x) - atan2(b_y, b_x)``.

    Parameters
    ----------
    target_in_observer, observer_in_target : ndarray, shape (2,)

    Returns
    -------
    float
        Yaw (rad, wrapped) of the target's frame in the observer's frame.
    """
    t = np.asarray(target_in_observer, dtype=float)
    b = np.asarray(observer_in_target, dtype=float)
    return float(wrap_angle(np.arctan2(-t[1], -t[0]) - np.arctan2(b[1], b[0])))


def covariance_intersection(a: np.ndarray, A: np.ndarray, b: np.ndarray, B: np.ndarray):
    """Fuse two pose estimates with unknown cross-correlation by covariance intersection [1]_.

    .. math:: C^{-1} = \\omega A^{-1} + (1 - \\omega) B^{-1}, \\quad
              c = C (\\omega A^{-1} a + (1 - \\omega) B^{-1} b)

    with ``omega`` in [0, 1] minimizing ``log det C`` (found by bisection: the objective is convex). The yaw of ``b`` is unwrapped next to ``a``'s.

    Parameters
    ----------
    a, b : ndarray, shape (3,)
    A, B : ndarray, shape (3, 3)
        Positive definite covariances.

    Returns
    -------
    mean : ndarray, shape (3,)
    cov : ndarray, shape (3, 3)
    omega : float
    """
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float).copy()
    b[2] = a[2] + wrap_angle(b[2] - a[2])
    Ai, Bi = np.linalg.inv(A), np.linalg.inv(B)
    # det(w Ai + (1-w) Bi) = det(Bi) prod(1 + w (lam - 1)) with lam the generalized eigenvalues of
    # (Ai, Bi), so -log det is a convex scalar function of w: bisect on its derivative
    lam = eigh(_sym(Ai), _sym(Bi), eigvals_only=True) - 1.0

    def slope(w: float) -> float:
        return float(-np.sum(lam / (1.0 + w * lam)))

    if slope(0.0) >= 0.0:
        w = 0.0
    elif slope(1.0) <= 0.0:
        w = 1.0
    else:
        lo, hi = 0.0, 1.0
        for _ in range(40):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if slope(mid) < 0.0 else (lo, mid)
        w = 0.5 * (lo + hi)
    C = np.linalg.inv(w * Ai + (1 - w) * Bi)
    c = C @ (w * Ai @ a + (1 - w) * Bi @ b)
    c[2] = wrap_angle(c[2])
    return c, _sym(C), w


def nees(error: np.ndarray, cov: np.ndarray) -> float:
    """Normalized estimation error squared ``e^T P^{-1} e`` (yaw component wrapped)."""
    e = np.asarray(error, dtype=float).copy()
    if e.shape[0] == 3:
        e[2] = wrap_angle(e[2])
    return float(e @ np.linalg.solve(cov, e))
