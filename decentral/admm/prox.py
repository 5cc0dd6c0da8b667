"""The proximal step of a pair or an assembly: a local problem plus penalty terms, solved by the certified relaxation.

It also holds the penalty metrics (:func:`scalar_metric`, :func:`pair_metric`) and residual balancing of the penalty
(:func:`balance_penalty`); docs/admm_method.md derives the homogenized problem these solvers hand to
:func:`decentral.relaxation.solve_low_rank`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from decentral.admm.config import AdmmConfig
from decentral.admm.forms import LocalProblem
from decentral.geometry import rot2
from decentral.relaxation import solve_low_rank

__all__ = ["ProxSolution", "balance_penalty", "pair_metric", "pose_columns", "scalar_metric", "solve_prox", "solve_prox_metric"]


@dataclass(frozen=True)
class ProxSolution:
    """Minimizer of a local problem plus prox terms.

    ``theta`` (n,) yaws and ``position`` (n, 3) in the gauge fixed by the prox targets (or the fixed
    variables); ``certified`` and ``min_eig`` come from the homogenized relaxation's certificate.
    """

    theta: np.ndarray
    position: np.ndarray
    certified: bool
    min_eig: float
    status: str

    @property
    def rotations(self) -> np.ndarray:
        return rot2(self.theta)


def _real_form(W: np.ndarray) -> np.ndarray:
    """Real (2n, 2n) ``Q`` whose Hermitian form (:mod:`decentral.relaxation`) is ``W`` (n, n)."""
    n = W.shape[0]
    Q = np.empty((n, 2, n, 2))
    Q[:, 0, :, 0] = Q[:, 1, :, 1] = 0.5 * W.real
    Q[:, 0, :, 1] = 0.5 * W.imag
    Q[:, 1, :, 0] = -0.5 * W.imag
    return Q.reshape(2 * n, 2 * n)


def _hermitian(Q: np.ndarray) -> np.ndarray:
    n = Q.shape[0] // 2
    B = Q.reshape(n, 2, n, 2)
    return (B[:, 0, :, 0] + B[:, 1, :, 1]) + 1j * (B[:, 0, :, 1] - B[:, 1, :, 0])


def scalar_metric(rho_R, rho_p) -> tuple[np.ndarray, np.ndarray]:
    """Penalty metric of scalar penalties: ``P_i = diag(rho_p_i, rho_R_i, rho_R_i)``, ``w_z = rho_p``.

    Returns ``P`` (n, 3, 3) over the columns ``[p_xy | R]`` of a pose and ``w_z`` (n,) for its height.
    """
    rho_R = np.atleast_1d(np.asarray(rho_R, float))
    rho_p = np.atleast_1d(np.asarray(rho_p, float))
    P = np.zeros((len(rho_R), 3, 3))
    P[:, 0, 0] = rho_p
    P[:, 1, 1] = P[:, 2, 2] = rho_R
    return P, rho_p.copy()


def pose_columns(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    """A pose as its ``2 x 3`` column block ``[p_xy | R]`` (the convention of ``X`` in the window form)."""
    return np.concatenate([np.asarray(p, float)[..., :2, None], np.asarray(R, float)], axis=-1)


def pair_metric(problem: LocalProblem, floor: float) -> tuple[np.ndarray, np.ndarray]:
    r"""Information-weighted penalty metric of a local problem: its diagonal Hessian blocks.

    For each variable ``i`` the ``3 x 3`` block of ``M`` over the columns ``[p_i | r_{i,1} | r_{i,2}]``
    (``sum_d w_d [1, q_d]^T [1, q_d]`` for a target, with the lever arms ``t_d`` for an observer),
    plus ``floor`` times its mean diagonal times the identity so that it is positive definite; the
    height weight is the block's ``p p`` entry. See the module docstring (matrix-weighted penalties).

    Returns
    -------
    P : ndarray, shape (n, 3, 3)
    w_z : ndarray, shape (n,)
    """
    n = problem.n
    P = np.empty((n, 3, 3))
    for i in range(n):
        c = [i, n + 2 * i, n + 2 * i + 1]
        P[i] = problem.M[np.ix_(c, c)]
    P = 0.5 * (P + P.transpose(0, 2, 1))
    scale = np.trace(P, axis1=1, axis2=2) / 3.0
    scale = np.where(scale > 0, scale, max(float(scale.max()), 1e-12))
    P += floor * scale[:, None, None] * np.eye(3)
    return P, P[:, 0, 0].copy()


def solve_prox(problem: LocalProblem, R_bar: np.ndarray, p_bar: np.ndarray, rho_R: np.ndarray,
               rho_p: np.ndarray, fixed: dict | None = None, theta0: np.ndarray | None = None) -> ProxSolution:
    r"""Minimize ``cost(x) + sum_i rho_R_i/2 ||R_i - R_bar_i||^2 + rho_p_i/2 ||p_i - p_bar_i||^2``.

    Scalar penalties; :func:`solve_prox_metric` with ``P_i = diag(rho_p_i, rho_R_i, rho_R_i)``.

    Parameters
    ----------
    problem : LocalProblem
        The factor cost over ``n`` variables.
    R_bar : ndarray, shape (n, 2, 2)
        Prox targets of the rotations (any 2 x 2 matrices: consensus minus scaled dual).
    p_bar : ndarray, shape (n, 3)
        Prox targets of the positions.
    rho_R, rho_p : ndarray, shape (n,)
        Non-negative penalties; every variable needs ``rho_p > 0`` or a factor path to a fixed one.
    fixed : dict, optional
        Variable index -> ``(theta, p)`` held fixed (the gauge pin).
    theta0 : ndarray, shape (n,), optional
        Warm start of the yaws.

    Returns
    -------
    ProxSolution
        Yaws and positions of all ``n`` variables (fixed ones at their values).
    """
    P, w_z = scalar_metric(rho_R, rho_p)
    B = pose_columns(np.asarray(R_bar, float), np.asarray(p_bar, float))
    return solve_prox_metric(problem, P, B @ P, w_z, w_z * np.asarray(p_bar, float)[:, 2], fixed, theta0)


def solve_prox_metric(problem: LocalProblem, P: np.ndarray, G: np.ndarray, w_z: np.ndarray, g_z: np.ndarray,
                      fixed: dict | None = None, theta0: np.ndarray | None = None) -> ProxSolution:
    r"""Minimize ``cost(x) + sum_i [1/2 tr(X_i P_i X_i^T) - tr(G_i^T X_i) + w_z_i/2 p_zi^2 - g_z_i p_zi]``.

    ``X_i = [p_xy,i | R_i]`` (2 x 3). A prox term ``1/2 ||X_i - B_i||^2_{P_i}`` is ``G_i = B_i P_i``;
    a sum of prox terms is the sum of their ``P`` and ``G``. Any symmetric ``P_i`` keeps the problem
    one over rotations only: ``r_{i,1} . r_{i,2} = 0`` and ``|r_{i,c}| = 1`` make the rotation-rotation
    part of ``P_i`` a constant, and its position-rotation part becomes, after the positions are
    eliminated, a form in ``cos, sin`` of yaw differences (a Hermitian form, as in
    :mod:`decentral.relaxation`).

    Parameters
    ----------
    problem : LocalProblem
        The factor cost over ``n`` variables.
    P : ndarray, shape (n, 3, 3)
        Symmetric positive semi-definite prox metrics over the columns ``[p_xy | R]``.
    G : ndarray, shape (n, 2, 3)
        Linear terms.
    w_z, g_z : ndarray, shape (n,)
        Height prox weight and linear term. Every variable needs ``P_i[0, 0] > 0`` and ``w_z_i > 0``
        or a factor path to a fixed one.
    fixed : dict, optional
        Variable index -> ``(theta, p)`` held fixed (the gauge pin).
    theta0 : ndarray, shape (n,), optional
        Warm start of the yaws.

    Returns
    -------
    ProxSolution
        Yaws and positions of all ``n`` variables (fixed ones at their values).
    """
    n = problem.n
    fixed = fixed or {}
    P = np.asarray(P, float)
    G = np.asarray(G, float)
    Mp = problem.M.copy()
    cix = np.stack([np.arange(n), n + 2 * np.arange(n), n + 2 * np.arange(n) + 1], 1)  # (n, 3) columns of x_i
    for i in range(n):
        Mp[np.ix_(cix[i], cix[i])] += 0.5 * P[i]
    # cost_xy = tr(X Mp X^T) + 2 sum(L * X)
    L = np.zeros((2, 3 * n))
    L[:, cix.ravel()] = -0.5 * G.transpose(1, 0, 2).reshape(2, 3 * n)
    Az = problem.M[:n, :n] + np.diag(0.5 * np.asarray(w_z, float))
    bz = problem.b_z + 0.5 * np.asarray(g_z, float)
    free = np.array([i for i in range(n) if i not in fixed], dtype=int)
    fix = np.array(sorted(fixed), dtype=int)
    cols = lambda idx: np.concatenate([idx, np.stack([n + 2 * idx, n + 2 * idx + 1], 1).ravel()])  # noqa: E731
    if len(fix):
        fc, xc = cols(free), cols(fix)
        Xfix = np.zeros((2, 3 * n))
        pz_fix = np.zeros(n)
        for i, (th, p) in fixed.items():
            Xfix[:, i] = p[:2]
            Xfix[:, n + 2 * i : n + 2 * i + 2] = rot2(th)
            pz_fix[i] = p[2]
        L_f = L[:, fc] + Xfix[:, xc] @ Mp[np.ix_(xc, fc)]
        Mf = Mp[np.ix_(fc, fc)]
        bz_f = bz[free] - Az[np.ix_(free, fix)] @ pz_fix[fix]
        Az_f = Az[np.ix_(free, free)]
    else:
        L_f, Mf, bz_f, Az_f = L, Mp, bz, Az
    nf = len(free)
    theta = np.zeros(n)
    position = np.zeros((n, 3))
    for i, (th, p) in fixed.items():
        theta[i], position[i] = th, p
    if nf == 0:
        return ProxSolution(theta, position, True, 0.0, "fixed")
    A, B, C = Mf[:nf, :nf], Mf[:nf, nf:], Mf[nf:, nf:]
    Lp, LR = L_f[:, :nf], L_f[:, nf:]
    AiB = np.linalg.solve(A, B)
    Q = C - B.T @ AiB  # positions eliminated (Schur complement, cf. Liu et al. 2024 after eq. (14))
    Q = 0.5 * (Q + Q.T)
    Gr = LR - Lp @ AiB  # linear term in the rotations: 2 sum_i tr(R_i^T G_i)
    gamma = (Gr[0, 0::2] + Gr[1, 1::2]) + 1j * (Gr[1, 0::2] - Gr[0, 1::2])
    W = np.zeros((nf + 1, nf + 1), complex)
    W[1:, 1:] = _hermitian(Q)
    W[1:, 0] = gamma  # homogenizing rotation z_0: 2 Re(gamma^H z) = z~^H [[0, gamma^H], [gamma, W]] z~
    W[0, 1:] = np.conj(gamma)
    th0 = None if theta0 is None else np.concatenate([[0.0], np.asarray(theta0, float)[free]])
    res = solve_low_rank(_real_form(W), th0)
    th = res.theta[1:] - res.theta[0]  # divide out the homogenizing rotation
    th = np.arctan2(np.sin(th), np.cos(th))
    Y = rot2(th).transpose(1, 0, 2).reshape(2, 2 * nf)
    Pxy = -np.linalg.solve(A, B @ Y.T + Lp.T)  # Liu et al. 2024 eq. (18) with the prox terms, (nf, 2)
    pz = np.linalg.solve(Az_f, bz_f)
    theta[free] = th
    position[free, :2] = Pxy
    position[free, 2] = pz
    return ProxSolution(theta, position, bool(res.certified), float(res.min_eig), res.status)


def balance_penalty(rho: float, r: float, s: float, config: AdmmConfig, lo: float, hi: float) -> float:
    """Residual balancing Boyd et al. 2011 §3.4.1: the new ``rho`` (the caller rescales its scaled duals by old/new)."""
    if r > config.mu * s:
        return min(rho * config.tau, hi)
    if s > config.mu * r:
        return max(rho / config.tau, lo)
    return rho
