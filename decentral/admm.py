r"""Consensus-ADMM over per-pair relaxed subproblems: the math every assembly agent runs.

Splitting
---------
A window (steps ``k-K+1 .. k``) has one pose variable ``x_{a,j} = (R_{a,j}, p_{a,j})`` per assembly
``a`` and step ``j`` (yaw ``R`` in SO(2), ``p`` in R^3). The joint cost of
:mod:`decentral.window` is a sum of visual factors (Liu et al. 2024 eq. (4)) and odometry factors
(eq. (7)). We split it by *directed observing pair*: ``e = (o -> a)`` holds every visual factor of
observer ``o``'s cameras seeing target ``a`` inside the window, and each assembly keeps its own
odometry chain:

.. math::

    F(x) = \sum_{e = (o \to a)} f_e(x_{o,\cdot}, x_{a,\cdot}) + \sum_a g_a(x_{a,\cdot}),

so the pair costs plus the assembly costs sum *exactly* to the joint cost (tested against
:func:`decentral.window.build_window`). Instead of splitting each odometry weight over the pairs,
the odometry stays with its assembly as the regularizer of its consensus update: this is global
variable consensus *with regularization* [1]_ §7.1.2. Pair ``e`` holds local copies ``y_e`` of the
poses of its two assemblies at the steps where it has factors; the consensus variable ``z_a`` (all
window poses of ``a``) is owned by ``a``'s agent. Scaled-form ADMM [1]_ §3.1.1, §7.1:

.. math::

    y_e^{t+1} &= \arg\min_{y \in (SO(2) \times \mathbb R^3)^{n_e}}
        f_e(y) + \tfrac{\rho_e}{2} \| y - z_e^t + u_e^t \|^2 \\
    z_a^{t+1} &= \arg\min_{z \in (SO(2) \times \mathbb R^3)^{K}}
        g_a(z) + \sum_{e \ni a} \tfrac{\rho_e}{2} \| z - (y_{e,a}^{t+1} + u_{e,a}^t) \|^2 \\
    u_e^{t+1} &= u_e^t + y_e^{t+1} - z_e^{t+1},

where the norms are *matrix weighted* (scaled ADMM, the metric selection of [2]_): pair ``e``
penalizes its copy of pose ``i`` with ``rho_e/2 tr((X - Z) P_{e,i} (X - Z)^T)`` over the columns
``X = [p_xy | R]`` of the pose (and ``rho_e/2 w_{e,i} (p_z - z_z)^2``), where ``P_{e,i}`` is the
``3 x 3`` diagonal block of the pair's own Hessian for that pose, ``sum_d w_d [1, q_d]^T [1, q_d]``
for a target (``t_d``, the metre-long lever arms, for an observer), plus a small floor
(:func:`pair_metric`). The consensus update is then an information-weighted average
``z = (sum_e rho_e P_e)^{-1} sum_e rho_e P_e (y_e + u_e)`` (with the odometry chain on top), and the
scaled duals keep the multiplier ``lambda = rho u P`` fixed when ``P`` changes. On the 8-ring this
cut the rounds of a warm window from 135 (scalar penalties) to 101. A scalar ``rho_e`` on top is
adapted by residual balancing [1]_ §3.4.1 (``r > mu s``: ``rho *= tau``, ``u /= tau``; ``s > mu r``: the
converse) with ``r = ||y - z||_P`` and ``s = rho ||z^{t+1} - z^t||_P``; with the information metric a
fixed ``rho`` is close to best, so ``mu`` defaults to 100 (a safeguard only). ADMM stops when the
primal residual and the consensus change are below absolute tolerances. With over-relaxation [1]_
§3.4.3 the consensus and dual updates use ``y_hat = alpha y + (1 - alpha) z`` in place of ``y``.

Both updates are the same kind of problem: a quadratic form ``tr(X M X^T)`` over ``X = [P_xy | R]``
(as in :mod:`decentral.window`) plus a prox term. Since ``||R||_F^2 = 2`` on SO(2), the prox term is
*linear* in each rotation, ``rho/2 ||R - B||^2 = const - rho tr(R^T B)``; positions are eliminated
in closed form (Schur complement with ``M_pp + diag(rho_p/2)``, positive definite thanks to the
prox), leaving

.. math:: \min_{z \in U(1)^n} z^H W z + 2 \operatorname{Re}(\gamma^H z)
    = \min \tilde z^H \begin{bmatrix} 0 & \gamma^H \\ \gamma & W \end{bmatrix} \tilde z,
    \quad \tilde z = (z_0, z), \; z_0 \equiv 1,

i.e. one more (homogenizing) rotation ``z_0`` whose value is divided out afterwards. That
``(n+1)``-rotation problem is solved by the core's certified low-rank solver
(:func:`decentral.relaxation.solve_low_rank`, SDP fallback), rounded per eq. (17); positions follow
per eq. (18). Variables can be held fixed (the gauge pin): their terms become linear terms of the
others.

Gauge: the reference assembly's agent pins its own pose at the window's first step to its current
consensus value (the identity at the very first window); no other agent pins anything, so the rule
needs no agreement. Consensus variables of an assembly that has never heard from a pair whose other
end is already in the pinned gauge stay *uninitialized*: pairs give them a vanishing penalty, and
they adopt the first copy that comes from an initialized neighbour (a breadth-first flood of the
gauge), which avoids averaging copies in unrelated gauges.

Warm starts: when the window slides, consensus values, copies and scaled duals of the steps that
remain are kept; a new step's consensus pose is the previous one moved by the odometry, and its duals
start from the previous step's multipliers.

Starting at a known solution (:meth:`PairState.seed`): at a minimizer ``x*`` of the joint cost, copies
``y = x*`` with duals ``u_{e,i} = -grad_i f_e(x*) P_{e,i}^{-1} / rho_e`` are a fixed point of the
iteration (each prox problem is stationary at ``y = z = x*``, and the consensus update sees the
joint gradient, which has no component along the poses' tangent spaces). Agents that share their
cost forms (a few hundred bytes per pair and step) can all compute ``x*`` with :func:`solve_joint`
and start there: the cold start then converges in a few rounds instead of hundreds. A spanning-tree
composition of pairwise relative poses is no substitute: a single pair fixes the target's position
well but its relative yaw poorly (a few nodes, a metre or two away), so composing around half a
16-ring was 7 m and 146 deg off the joint estimate.

Why plain ADMM stays slow on rings: the joint window problem is ill-conditioned in a way no local
metric removes. The Hessian of the 16-ring window (2 steps, gauge fixed) scaled by its block
diagonal (the best local metric) has condition number ``kappa`` 7.6e3 (1.1e3 for 8, 2e5 for 32
assemblies: the ring's long "bending" mode, in which small relative-yaw errors of every pair add up).
ADMM on a quadratic with optimally chosen penalty converges at best like
``((sqrt(kappa) - 1) / (sqrt(kappa) + 1))^t`` [3]_, i.e. ~300 rounds per 1000x error reduction at
``kappa`` 7.6e3; measured warm windows on the 16-ring contract by ~0.9925 per round. Neither
over-relaxation nor penalty adaptation changes the order; Nesterov-type acceleration with restart [4]_
needs a global restart test (with local restarts it lost its gain in a model of the ring). Only
exchanging second-order information (the forms) beats it; see ``share_forms`` in
:mod:`agents.assembly`.

References
----------
.. [1] S. Boyd, N. Parikh, E. Chu, B. Peleato, J. Eckstein, "Distributed optimization and statistical
   learning via the alternating direction method of multipliers", Foundations and Trends in Machine
   Learning 3(1), 2011.
.. [2] P. Giselsson, S. Boyd, "Linear convergence and metric selection for Douglas-Rachford splitting
   and ADMM", IEEE Transactions on Automatic Control 62(2), 2017.
.. [3] E. Ghadimi, A. Teixeira, I. Shames, M. Johansson, "Optimal parameter selection for the
   alternating direction method of multipliers (ADMM): quadratic problems", IEEE Transactions on
   Automatic Control 60(3), 2015.
.. [4] T. Goldstein, B. O'Donoghue, S. Setzer, R. Baraniuk, "Fast alternating direction optimization
   methods", SIAM Journal on Imaging Sciences 7(3), 2014.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from decentral.errors import InputError
from decentral.estimator import placeable_yaws
from decentral.geometry import rot2
from decentral.relaxation import recover_positions, reduce_rotations, solve_low_rank

__all__ = [
    "AdmmConfig",
    "LocalProblem",
    "ProxSolution",
    "quadratic_form",
    "solve_prox",
    "solve_prox_metric",
    "scalar_metric",
    "pose_columns",
    "pair_metric",
    "solve_joint",
    "JointSolution",
    "balance_penalty",
    "PairState",
    "ConsensusState",
    "Pose2",
]

#: a planar pose value: (2, 2) rotation and (3,) position
Pose2 = tuple[np.ndarray, np.ndarray]


@dataclass(frozen=True)
class AdmmConfig:
    """Parameters of the consensus-ADMM.

    Attributes
    ----------
    rho0 : float
        Initial penalty scale: pair ``e`` penalizes key ``i`` with ``rho P_{e,i}``, ``rho = rho0`` at
        the start, ``P`` the information metric (or the mean curvature, ``metric="scalar"``).
    mu, tau : float
        Residual balancing: rescale ``rho`` by ``tau`` when one residual exceeds ``mu`` times the other.
    rho_span : float
        ``rho`` stays within ``[rho_init / rho_span, rho_init * rho_span]``.
    eps_rot : float
        Absolute tolerance on the rotation residuals (Frobenius norm of 2 x 2 blocks, ~ radians).
    eps_pos : float
        Absolute tolerance on the position residuals (metres).
    balance_every : int
        Adapt ``rho`` every this many pair iterations (1: every iteration).
    alpha : float
        Over-relaxation [1]_ §3.4.3 (1: none; 1.5-1.8 typical).
    metric : {"information", "scalar"}
        Penalty metric per key: the pair's diagonal Hessian block (:func:`pair_metric`) or a scalar
        per rotation / position (the pair's mean curvatures).
    metric_floor : float
        Regularization of the information metric, relative to its mean diagonal.
    carry_duals : bool
        A new step's duals start from the previous step's multipliers (:meth:`PairState.set_problem`).
    tail : float
        Convergence also needs the predicted remaining consensus change
        (:meth:`ConsensusState.remaining`) below ``tail`` times the tolerances.

    Defaults, measured on the 8-ring (K = 5, 6 steps, the first started from the shared forms; rounds
    of steps 2-6): information metric, rho0 0.3, floor 0.005, alpha 1.8, mu 100: 84, 95, 118, 91, 142;
    mu 1e6 (no balancing): 84, 101, 119, 102, 134; mu 3: 110, 133, 140, 118, 148; mu 10: 132, 138,
    155, 132, 181; rho0 1, floor 0.05, alpha 1.5, mu 3: 91, 105, 110, 103, 146; scalar metric (rho0 1,
    mu 3, alpha 1.5): 110, 115, 112, 133 (4 steps). On a seeded 8-ring step (one warm window): floor
    0.005 101, 0.05 109, 0.2 125, 1.0 175 rounds; scalar metric 135; rho0 0.1 ~200, 0.2 117, 0.5 135,
    1 ~220 (alpha 1.5, no balancing).
    """

    rho0: float = 0.3
    mu: float = 100.0
    tau: float = 2.0
    rho_span: float = 1e4
    eps_rot: float = 3e-5
    eps_pos: float = 3e-5
    balance_every: int = 1
    alpha: float = 1.8
    metric: str = "information"
    metric_floor: float = 0.005
    carry_duals: bool = True
    tail: float = 10.0

    def __post_init__(self) -> None:
        if not (self.rho0 > 0 and self.mu > 1 and self.tau > 1 and self.rho_span >= 1):
            raise InputError("need rho0 > 0, mu > 1, tau > 1, rho_span >= 1", field="admm")
        if not (self.eps_rot > 0 and self.eps_pos > 0):
            raise InputError("tolerances must be positive", field="admm")
        if not (isinstance(self.balance_every, int) and self.balance_every >= 1):
            raise InputError("balance_every must be an integer >= 1", field="admm")
        if not 0 < self.alpha < 2:
            raise InputError("alpha must be in (0, 2)", field="admm")
        if self.metric not in ("information", "scalar"):
            raise InputError("metric must be 'information' or 'scalar'", field="admm")
        if not self.metric_floor > 0:
            raise InputError("metric_floor must be positive", field="admm")


@dataclass(frozen=True)
class LocalProblem:
    """A quadratic form over ``n`` pose variables, the convention of :class:`decentral.window.WindowProblem`.

    Attributes
    ----------
    keys : tuple
        One hashable key per variable (``(assembly, step)``).
    M : ndarray, shape (3n, 3n)
        xy form over ``[P_xy | R2_1 .. R2_n]``.
    b_z : ndarray, shape (n,)
        z normal equations right-hand side (``cost_z = p_z^T M_pp p_z - 2 b_z^T p_z + c_z``).
    c_z : float
        Constant of the z cost.
    """

    keys: tuple
    M: np.ndarray
    b_z: np.ndarray
    c_z: float

    @property
    def n(self) -> int:
        return len(self.keys)

    def cost(self, theta: np.ndarray, position: np.ndarray) -> float:
        """Joint cost at yaws ``theta`` (n,) and positions (n, 3)."""
        n = self.n
        X = np.hstack([position[:, :2].T, rot2(theta).transpose(1, 0, 2).reshape(2, 2 * n)])
        pz = position[:, 2]
        return float(np.trace(X @ self.M @ X.T) + pz @ self.M[:n, :n] @ pz - 2 * self.b_z @ pz + self.c_z)


def quadratic_form(keys, visual=None, odometry=None) -> LocalProblem:
    """Sum of weighted factor outer products over ``keys`` (Liu et al. 2024 eq. (5), (8), (11)).

    Parameters
    ----------
    keys : sequence
        Variable keys, ``n`` of them.
    visual : tuple of arrays, optional
        ``(io, ia, q, t, w)``: observer and target variable indices (d,), node centre in the target
        root frame ``q`` (d, 3), measured centre in the observer root frame ``t`` (d, 3) (eq. (4)),
        weights (d,).
    odometry : tuple of arrays, optional
        ``(iv, iu, dp, dtheta, w_p, w_R)``: variable at the previous step and at the step (e,),
        translation (e, 3) in the previous root frame, yaw increment (e,), weights (e,), (e,).
    """
    keys = tuple(keys)
    n = len(keys)
    rows_C, rows_w, rows_s = [], [], []
    M = np.zeros((3 * n, 3 * n))
    if visual is not None and len(visual[0]):
        io, ia, q, t, w = (np.asarray(a) for a in visual)
        C = np.zeros((len(io), 3 * n))
        r = np.arange(len(io))
        # Liu et al. 2024 eq. (4): e = R_a q + p_a - p_o - R_o t
        np.add.at(C, (r, ia), 1.0)
        np.add.at(C, (r, io), -1.0)
        np.add.at(C, (r, n + 2 * ia), q[:, 0])
        np.add.at(C, (r, n + 2 * ia + 1), q[:, 1])
        np.add.at(C, (r, n + 2 * io), -t[:, 0])
        np.add.at(C, (r, n + 2 * io + 1), -t[:, 1])
        rows_C.append(C), rows_w.append(np.asarray(w, float)), rows_s.append(q[:, 2] - t[:, 2])
    if odometry is not None and len(odometry[0]):
        iv, iu, dp, dth, w_p, w_R = (np.asarray(a) for a in odometry)
        C = np.zeros((len(iv), 3 * n))
        r = np.arange(len(iv))
        # Liu et al. 2024 eq. (7), position: e = p_u - p_v - R_v dp
        np.add.at(C, (r, iu), 1.0)
        np.add.at(C, (r, iv), -1.0)
        np.add.at(C, (r, n + 2 * iv), -dp[:, 0])
        np.add.at(C, (r, n + 2 * iv + 1), -dp[:, 1])
        rows_C.append(C), rows_w.append(np.asarray(w_p, float)), rows_s.append(-dp[:, 2])
        # Liu et al. 2024 eq. (7), rotation: ||R_u - R_v R̂||_F^2
        B = M[n:, n:].reshape(n, 2, n, 2)  # a view into M
        Rh = rot2(np.asarray(dth, float))
        for j in range(len(iv)):
            B[iu[j], :, iu[j], :] += w_R[j] * np.eye(2)
            B[iv[j], :, iv[j], :] += w_R[j] * np.eye(2)
            B[iu[j], :, iv[j], :] -= w_R[j] * Rh[j].T
            B[iv[j], :, iu[j], :] -= w_R[j] * Rh[j]
    if rows_C:
        C = np.vstack(rows_C)
        w = np.concatenate(rows_w)
        s = np.concatenate(rows_s)
        M += C.T @ (w[:, None] * C)
        Cp = C[:, :n]
        b_z = -Cp.T @ (w * s)
        c_z = float(np.sum(w * s * s))
    else:
        b_z, c_z = np.zeros(n), 0.0
    return LocalProblem(keys, M, b_z, c_z)


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
    """Residual balancing [1]_ §3.4.1: the new ``rho`` (the caller rescales its scaled duals by old/new)."""
    if r > config.mu * s:
        return min(rho * config.tau, hi)
    if s > config.mu * r:
        return max(rho / config.tau, lo)
    return rho


def _yaw(R: np.ndarray) -> float:
    return float(np.arctan2(R[1, 0], R[0, 0]))


def _cols(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    return np.concatenate([p[:2, None], R], axis=1)


def _metric_norm2(d: np.ndarray, dz: float, P: np.ndarray, w_z: float) -> float:
    """``||Delta||^2`` in the metric ``(P, w_z)`` of a pose difference given as columns ``d`` (2, 3) and height ``dz``."""
    return float(np.sum((d @ P) * d) + w_z * dz * dz)


class PairState:
    """ADMM state of one directed observing pair ``observer -> target``, kept by the observer's agent.

    The pair's local copies ``y`` cover the window steps at which it has visual factors. Call
    :meth:`set_problem` whenever the window or the factors change (copies and duals of the keys that
    remain are kept: the warm start), then :meth:`iterate` once per ADMM round with the newest
    consensus values. Its penalty on key ``i`` is ``rho * P_i`` (and ``rho * w_z_i`` on the height):
    the information metric of :func:`pair_metric` (``AdmmConfig.metric = "information"``) or the
    scalar one, ``P_i = diag(c_p, c_R, c_R)`` with the pair's mean curvatures (``"scalar"``).
    """

    def __init__(self, observer: str, target: str, config: AdmmConfig):
        self.observer, self.target, self.config = observer, target, config
        self.problem: LocalProblem | None = None
        self.y: dict = {}  # key -> Pose2 (local copy)
        self.u: dict = {}  # key -> Pose2-shaped scaled dual (2x2, 3)
        self.z_used: dict = {}  # key -> Pose2 consensus used in the last dual update
        self.base: dict = {}  # key -> (P (3, 3), w_z): the metric before the scale rho
        self.rho = config.rho0
        self.r_R = self.r_p = self.c_R = self.c_p = np.inf
        self.iterations = 0
        self.certified = True
        self.live_prev: set = set()
        self.y_hat: dict = {}

    def set_problem(self, problem: LocalProblem) -> None:
        """Install the pair's factor cost for the current window, keeping state of surviving keys.

        A new key ``(assembly, step)`` whose predecessor ``(assembly, step - 1)`` had a dual starts
        with the predecessor's multiplier ``lambda = u P`` (``AdmmConfig.carry_duals``): consecutive
        frames see nearly the same scene, so the pair's "force" on the assembly is nearly the same, and
        the new step starts close to the ADMM fixed point instead of at ``u = 0``.
        """
        keep = set(problem.keys)
        carried = {}
        if self.config.carry_duals:
            for k in problem.keys:
                prev = (k[0], k[1] - 1)
                if k not in self.u and prev in self.u and prev in self.base:
                    carried[k] = (self.u[prev], self.base[prev])
        self.y = {k: v for k, v in self.y.items() if k in keep}
        self.u = {k: v for k, v in self.u.items() if k in keep}
        self.z_used = {k: v for k, v in self.z_used.items() if k in keep}
        self.problem = problem
        n = problem.n
        if n == 0:
            self.base = {}
            return
        if self.config.metric == "information":
            P, w_z = pair_metric(problem, self.config.metric_floor)
        else:
            c_p = float(np.trace(problem.M[:n, :n])) / n
            c_R = float(np.trace(problem.M[n:, n:])) / (2 * n)
            P, w_z = scalar_metric(np.full(n, c_R), np.full(n, c_p))
        base = {k: (P[i], float(w_z[i])) for i, k in enumerate(problem.keys)}
        for k, (u_prev, metric_prev) in carried.items():
            self.u[k] = u_prev
            self.base[k] = metric_prev  # converted to the new metric below
        for k, (uR, up) in list(self.u.items()):
            old = self.base.get(k)
            if old is not None and not (np.array_equal(old[0], base[k][0]) and old[1] == base[k][1]):
                # keep the unscaled multiplier lambda = U P fixed when the metric changes
                U = _cols(uR, up) @ old[0] @ np.linalg.inv(base[k][0])
                self.u[k] = (U[:, 1:], np.array([U[0, 0], U[1, 0], up[2] * old[1] / base[k][1]]))
        self.base = base

    def seed(self, values: dict) -> bool:
        """Start from a known joint solution: copies at ``values`` and the duals that make it a fixed point.

        At a minimizer ``x*`` of the joint cost the copy update returns ``y = x*`` exactly when
        ``grad f_e(x*) + rho u P = 0`` (stationarity of the prox problem at ``y = z = x*``), i.e.
        ``u = -grad f_e(x*) P^{-1} / rho`` per key; the consensus update then sees
        ``sum_e grad f_e + grad g_a = grad F(x*)``, which has no component along SO(2) x R^3, so ``x*``
        is a fixed point of the whole iteration [1]_ §3.3 (optimality conditions). Returns whether
        every key of the pair had a value.
        """
        prob = self.problem
        if prob is None or prob.n == 0 or not all(k in values for k in prob.keys):
            return False
        keys = prob.keys
        n = prob.n
        theta = np.array([_yaw(values[k][0]) for k in keys])
        position = np.array([values[k][1] for k in keys], float)
        X = np.hstack([position[:, :2].T, rot2(theta).transpose(1, 0, 2).reshape(2, 2 * n)])
        grad = 2.0 * X @ prob.M  # d/dX tr(X M X^T)
        grad_z = 2.0 * (prob.M[:n, :n] @ position[:, 2] - prob.b_z)
        for i, k in enumerate(keys):
            P, w_z = self.base[k]
            G = grad[:, [i, n + 2 * i, n + 2 * i + 1]]
            U = -np.linalg.solve(P, G.T).T / self.rho
            self.u[k] = (U[:, 1:], np.array([U[0, 0], U[1, 0], -grad_z[i] / (self.rho * w_z)]))
            self.y[k] = (rot2(theta[i]), position[i].copy())
        self.y_hat = dict(self.y)
        self.z_used = dict(self.y)
        self.live_prev = set(keys)
        return True

    @property
    def rho_R(self) -> float:
        """Mean penalty on the rotation columns (for reports)."""
        if not self.base:
            return 0.0
        return self.rho * float(np.mean([0.5 * (P[1, 1] + P[2, 2]) for P, _ in self.base.values()]))

    @property
    def rho_p(self) -> float:
        """Mean penalty on the positions (for reports)."""
        if not self.base:
            return 0.0
        return self.rho * float(np.mean([P[0, 0] for P, _ in self.base.values()]))

    def metric(self, key) -> tuple[np.ndarray, float]:
        """The penalty ``(rho P, rho w_z)`` of one key."""
        P, w_z = self.base[key]
        return self.rho * P, self.rho * w_z

    @property
    def residuals(self) -> tuple[float, float, float, float]:
        """``(r_R, r_p, c_R, c_p)`` of the last iteration: primal residual and consensus change."""
        return self.r_R, self.r_p, self.c_R, self.c_p

    def converged(self) -> bool:
        """Primal residual and consensus change below the tolerances."""
        c = self.config
        return max(self.r_R, self.c_R) <= c.eps_rot and max(self.r_p, self.c_p) <= c.eps_pos

    def iterate(self, z: dict, ready: dict) -> tuple[dict, dict]:
        """One ADMM iteration: dual update with ``z``, penalty balancing, then the copy update.

        Parameters
        ----------
        z : dict
            key -> consensus value ``Pose2`` for every key whose assembly's consensus is known.
        ready : dict
            assembly name -> whether its consensus is in the pinned gauge (initialized).

        Returns
        -------
        values : dict
            key -> ``(y_hat + u)`` as ``Pose2``: what the owning assembly averages.
        metrics : dict
            key -> ``(P (3, 3), w_z)``: the weight of that value in the owner's consensus update.
        """
        prob = self.problem
        if prob is None or prob.n == 0:
            return {}, {}
        keys = prob.keys
        live = [k for k in keys if ready.get(k[0], False) and k in z]
        # dual update u += y - z and residuals (Boyd §3.3): only for copies that were live in the last
        # copy update too (a copy made before its assembly joined the gauge says nothing about z)
        both = [k for k in live if k in self.live_prev and k in self.y_hat]
        if both:
            rR = rp = sR = sp = 0.0
            r_w = s_w = 0.0
            have_prev = True
            for k in both:
                zR, zp = z[k]
                yR, yp = self.y_hat[k]
                uR, up = self.u.get(k, (np.zeros((2, 2)), np.zeros(3)))
                self.u[k] = (uR + yR - zR, up + yp - zp)
                rR += float(np.sum((yR - zR) ** 2))
                rp += float(np.sum((yp - zp) ** 2))
                P, w_z = self.base[k]
                r_w += _metric_norm2(_cols(yR - zR, yp - zp), yp[2] - zp[2], P, w_z)
                if k in self.z_used:
                    dR, dp = zR - self.z_used[k][0], zp - self.z_used[k][1]
                    sR += float(np.sum(dR ** 2))
                    sp += float(np.sum(dp ** 2))
                    s_w += _metric_norm2(_cols(dR, dp), dp[2], P, w_z)
                else:
                    have_prev = False
            self.r_R, self.r_p = np.sqrt(rR), np.sqrt(rp)
            self.c_R, self.c_p = (np.sqrt(sR), np.sqrt(sp)) if have_prev else (np.inf, np.inf)
            busy = max(self.r_R, self.c_R) > self.config.eps_rot or max(self.r_p, self.c_p) > self.config.eps_pos
            if self.iterations % self.config.balance_every == 0 and have_prev and s_w > 0 and busy:
                # Boyd §3.4.1 in the penalty metric: r = ||y - z||_P, s = rho ||z - z_prev||_P
                lo, hi = self.config.rho0 / self.config.rho_span, self.config.rho0 * self.config.rho_span
                new = balance_penalty(self.rho, np.sqrt(r_w), self.rho * np.sqrt(s_w), self.config, lo, hi)
                factor = new / self.rho
                if factor != 1.0:
                    self.rho = new
                    for k in self.u:
                        uR, up = self.u[k]
                        self.u[k] = (uR / factor, up / factor)
        else:
            self.r_R = self.r_p = self.c_R = self.c_p = np.inf
        for k in live:
            self.z_used[k] = z[k]
        self.live_prev = set(live)
        # copy update: prox towards z - u (live keys) or a vanishing pull to the last copy (others)
        n = prob.n
        P = np.zeros((n, 3, 3))
        G = np.zeros((n, 2, 3))
        w_z = np.zeros(n)
        g_z = np.zeros(n)
        theta0 = np.zeros(n)
        tiny = 1e-9
        for i, k in enumerate(keys):
            Pk, wk = self.base[k]
            if k in live:
                zR, zp = z[k]
                uR, up = self.u.get(k, (np.zeros((2, 2)), np.zeros(3)))
                Rb, pb = zR - uR, zp - up
                weight = self.rho
                theta0[i] = _yaw(self.y[k][0]) if k in self.y else _yaw(zR)
            else:
                Rb, pb = self.y.get(k) or z.get(k) or (np.eye(2), np.zeros(3))
                weight = tiny * self.rho
                theta0[i] = _yaw(Rb)
            P[i], w_z[i] = weight * Pk, weight * wk
            G[i] = _cols(Rb, pb) @ P[i]
            g_z[i] = w_z[i] * pb[2]
        sol = solve_prox_metric(prob, P, G, w_z, g_z, theta0=theta0)
        self.certified = sol.certified
        R = sol.rotations
        self.y = {k: (R[i], sol.position[i]) for i, k in enumerate(keys)}
        # over-relaxation (Boyd §3.4.3): y_hat = alpha y + (1 - alpha) z
        a = self.config.alpha
        self.y_hat = {k: ((a * y[0] + (1 - a) * z[k][0], a * y[1] + (1 - a) * z[k][1]) if k in live else y)
                      for k, y in self.y.items()}
        self.iterations += 1
        values, metrics = {}, {}
        for k in keys:
            uR, up = self.u.get(k, (np.zeros((2, 2)), np.zeros(3)))
            if k not in live:
                uR, up = np.zeros((2, 2)), np.zeros(3)
            values[k] = (self.y_hat[k][0] + uR, self.y_hat[k][1] + up)
            metrics[k] = self.metric(k)
        return values, metrics


class ConsensusState:
    """The consensus poses ``z_a`` of one assembly over the window, with its odometry regularizer.

    Parameters
    ----------
    name : str
        The assembly.
    pinned : bool
        Whether this assembly fixes the gauge (its pose at the window's first step is held).
    """

    def __init__(self, name: str, pinned: bool):
        self.name, self.pinned = name, pinned
        self.steps: list[int] = []
        self.z: dict[int, Pose2] = {}
        self.ready = pinned
        self.odometry: dict[int, tuple] = {}  # step -> (dp, dtheta, w_p, w_R)
        self.change = np.inf
        self.changes: list[float] = []  # recent consensus changes (for the tail bound)
        self.pin: tuple[int, float, np.ndarray] | None = None

    def remaining(self) -> float:
        r"""A-posteriori bound on the distance still to go: ``c (1 + q / (1 - q))``.

        ``c`` is the last consensus change and ``q`` the median ratio of the last changes (a linearly
        converging sequence moves at most ``c q / (1 - q)`` more), capped at 0.999. On ill-conditioned
        rings ``q`` is close to 1 and a small change alone says little: on the 16-ring the change fell
        below 3e-5 while the estimate was still 1.8 mm from the joint solution.
        """
        c = self.change
        h = self.changes[-5:]
        ratios = [b / a for a, b in zip(h, h[1:]) if a > 0]
        if not np.isfinite(c) or not ratios:
            return c
        q = min(max(float(np.median(ratios)), 0.0), 0.999)
        return c * (1.0 + q / (1.0 - q))

    def slide(self, steps: list[int], odometry: dict[int, tuple]) -> None:
        """Move to a new window ``steps``; new steps are predicted by odometry from the previous one."""
        self.odometry = {k: v for k, v in odometry.items() if k in steps}
        for k in steps:
            if k not in self.z and (k - 1) in self.z:
                R, p = self.z[k - 1]
                if k in self.odometry:
                    dp, dth = self.odometry[k][0], self.odometry[k][1]
                    Rz = np.eye(3)
                    Rz[:2, :2] = R
                    self.z[k] = (R @ rot2(dth), p + Rz @ dp)
                else:
                    self.z[k] = (R.copy(), p.copy())
            elif k not in self.z:
                self.z[k] = (np.eye(2), np.zeros(3))
        self.z = {k: self.z[k] for k in steps}
        self.steps = list(steps)
        if self.pinned:
            first = steps[0]
            R, p = self.z[first]
            self.pin = (first, _yaw(R), p.copy())
            self.ready = True
        self.change = np.inf
        self.changes = []

    def seed(self, values: dict[int, Pose2]) -> None:
        """Adopt known consensus poses (step -> Pose2) for the steps of the window it has values for."""
        if not any(k in values for k in self.steps):
            return
        for k in self.steps:
            if k in values:
                R, p = values[k]
                self.z[k] = (np.array(R, float), np.array(p, float))
        if self.pinned and self.steps:
            first = self.steps[0]
            R, p = self.z[first]
            self.pin = (first, _yaw(R), p.copy())
        self.ready = True
        self.change = np.inf
        self.changes = []

    def anchored(self, step: int, factor_steps: set[int]) -> bool:
        """Whether ``step`` is tied by odometry to a step with visual factors (or to the pin)."""
        if not self.ready:
            return False
        tied = set(factor_steps)
        if self.pin is not None:
            tied.add(self.pin[0])
        k = step
        while True:
            if k in tied:
                return True
            if k not in self.odometry or (k - 1) not in self.z:
                return False
            k -= 1

    def odometry_problem(self) -> LocalProblem | None:
        """The odometry chain's quadratic form over the window steps (``None`` without odometry)."""
        steps = self.steps
        idx = {k: i for i, k in enumerate(steps)}
        odo = [(idx[k - 1], idx[k]) + tuple(self.odometry[k]) for k in steps if k in self.odometry and (k - 1) in idx]
        if not odo:
            return None
        iv, iu, dp, dth, wp, wR = zip(*odo)
        return quadratic_form([(self.name, k) for k in steps], odometry=(
            np.array(iv), np.array(iu), np.array(dp), np.array(dth), np.array(wp), np.array(wR)))

    def odometry_links(self) -> list[LocalProblem]:
        """The odometry chain as one form per link ``(step - 1, step)`` of the window; they sum to
        :meth:`odometry_problem` and, like it, tie every window step (a link without odometry is a zero
        form), so that the joint problem's variables are the same (empty without odometry)."""
        if not any(k in self.odometry and (k - 1) in self.steps for k in self.steps):
            return []
        out = []
        for k in self.steps:
            if (k - 1) not in self.steps:
                continue
            keys = [(self.name, k - 1), (self.name, k)]
            if k in self.odometry:
                dp, dth, wp, wR = self.odometry[k]
                out.append(quadratic_form(keys, odometry=(np.array([0]), np.array([1]), np.array([dp]),
                                                          np.array([dth]), np.array([wp]), np.array([wR]))))
            else:
                out.append(quadratic_form(keys))
        return out

    def update(self, contributions: list[tuple[dict, dict]]) -> bool:
        r"""Consensus update from pair contributions ``(step -> (y + u), step -> (P, w_z))``.

        Minimizes the odometry chain cost plus ``sum_e 1/2 ||z_k - v_{e,k}||^2_{P_{e,k}}``: a
        matrix-weighted average when there is no odometry. Returns whether the consensus changed
        (False when nothing usable arrived yet).
        """
        if not self.steps:
            return False
        if not contributions and not self.pinned:
            return False
        steps = self.steps
        idx = {k: i for i, k in enumerate(steps)}
        n = len(steps)
        odo = [(idx[k - 1], idx[k]) + tuple(self.odometry[k]) for k in steps if k in self.odometry and (k - 1) in idx]
        if odo:
            iv, iu, dp, dth, wp, wR = zip(*odo)
            prob = quadratic_form(steps, odometry=(np.array(iv), np.array(iu), np.array(dp), np.array(dth),
                                                   np.array(wp), np.array(wR)))
        else:
            prob = quadratic_form(steps)
        P = np.zeros((n, 3, 3))
        G = np.zeros((n, 2, 3))
        w_z = np.zeros(n)
        g_z = np.zeros(n)
        scale = 0.0
        for values, metrics in contributions:
            for k, (VR, Vp) in values.items():
                if k in idx and k in metrics:
                    i = idx[k]
                    Pk, wk = metrics[k]
                    P[i] += Pk
                    G[i] += _cols(VR, Vp) @ Pk
                    w_z[i] += wk
                    g_z[i] += wk * Vp[2]
                    scale = max(scale, float(np.trace(Pk)) / 3)
        # a vanishing pull to the current value keeps steps without factors well posed
        tiny = 1e-9 * max(scale, float(np.trace(prob.M)) / (3 * n), 1e-12)
        cur_R = np.array([self.z[k][0] for k in steps])
        cur_p = np.array([self.z[k][1] for k in steps])
        for i in range(n):
            P[i] += tiny * np.eye(3)
            G[i] += tiny * _cols(cur_R[i], cur_p[i])
        w_z += tiny
        g_z += tiny * cur_p[:, 2]
        fixed = {}
        if self.pinned and self.pin is not None and self.pin[0] in idx:
            fixed[idx[self.pin[0]]] = (self.pin[1], self.pin[2])
        theta0 = np.array([_yaw(R) for R in cur_R])
        sol = solve_prox_metric(prob, P, G, w_z, g_z, fixed=fixed, theta0=theta0)
        R = sol.rotations
        change = 0.0
        for i, k in enumerate(steps):
            change = max(change, float(np.abs(R[i] - cur_R[i]).max()), float(np.abs(sol.position[i] - cur_p[i]).max()))
            self.z[k] = (R[i], sol.position[i])
        self.change = change
        self.changes = (self.changes + [change])[-6:]
        self.ready = True
        return True


def _joint_form(problems: list[LocalProblem], fixed_key) -> tuple[list, dict, np.ndarray, np.ndarray]:
    """The summed window form over the variables connected to ``fixed_key``.

    Returns the keys (sorted), key -> index, ``M`` (3n, 3n) over ``[P_xy | R]`` and ``b_z`` (n,).
    """
    edges: dict = {}
    for prob in problems:
        for a in prob.keys:
            edges.setdefault(a, set()).update(prob.keys)
    comp, todo = {fixed_key}, [fixed_key]
    while todo:
        for b in edges.get(todo.pop(), ()):
            if b not in comp:
                comp.add(b)
                todo.append(b)
    keys = sorted(comp, key=repr)
    index = {k: i for i, k in enumerate(keys)}
    n = len(keys)
    M = np.zeros((3 * n, 3 * n))
    b_z = np.zeros(n)
    for prob in problems:
        if prob.keys[0] not in index:
            continue
        g = np.array([index[k] for k in prob.keys])
        gc = np.concatenate([g, np.stack([n + 2 * g, n + 2 * g + 1], 1).ravel()])
        m = prob.n
        lc = np.concatenate([np.arange(m), np.stack([m + 2 * np.arange(m), m + 2 * np.arange(m) + 1], 1).ravel()])
        M[np.ix_(gc, gc)] += prob.M[np.ix_(lc, lc)]
        b_z[g] += prob.b_z
    return keys, index, M, b_z


@dataclass(frozen=True)
class JointSolution:
    """The joint window of the shared forms, solved (:func:`solve_joint`).

    Attributes
    ----------
    poses : dict
        key -> ``Pose2`` for every variable connected to the gauge variable.
    index : dict
        key -> index into ``theta`` and the rows of ``Q``.
    Q : ndarray, shape (2m, 2m)
        The rotation-only cost after eliminating positions (Liu et al. 2024 eq. (14)); empty for one variable.
    theta : ndarray, shape (m,)
        The yaws at the optimum.
    """

    poses: dict
    index: dict
    Q: np.ndarray
    theta: np.ndarray

    def placeable(self, reference, max_yaw_std: float) -> frozenset:
        """Keys at ``reference``'s step that the centralized estimator would place relative to it.

        The same test as :func:`decentral.estimator.placeable_yaws` (the relative yaw is outside the
        null space of the yaw Hessian and its Laplace standard deviation is at most ``max_yaw_std``);
        nothing when ``reference`` is not tied to the gauge variable.
        """
        return self.placement(reference, max_yaw_std)[0]

    def placement(self, reference, max_yaw_std: float) -> tuple[frozenset, dict]:
        """:meth:`placeable` and the relative-yaw standard deviations (assembly -> rad) it tested."""
        if reference not in self.index or len(self.index) == 1:
            return frozenset(), {}
        return placeable_yaws(self.Q, self.theta, self.index, reference, max_yaw_std)


def solve_joint(problems: list[LocalProblem], fixed_key, fixed_value: Pose2 | None = None) -> JointSolution:
    r"""Minimize the sum of local problems over the variables tied to ``fixed_key`` (held fixed).

    The cold start of the ADMM: the pair forms of one step, shared by every agent, summed into the
    joint problem (their sum is the joint cost, as for :func:`decentral.window.build_window`),
    restricted to the connected component of the gauge variable, solved gauge-free like the
    centralized window (rotations eliminated per Liu et al. 2024 eq. (14), the certified low-rank solve,
    positions per eq. (18)) and moved rigidly so that the gauge variable takes its value (identity by
    default). Deterministic in its inputs, so agents that hold the same forms get bit-identical answers.

    Parameters
    ----------
    problems : list of LocalProblem
        The forms (any keys; a key shared by several forms is one variable).
    fixed_key : hashable
        The gauge variable.
    fixed_value : Pose2, optional
        Its value; the identity by default.

    Returns
    -------
    JointSolution
        Its ``poses``: key -> ``Pose2`` for every variable connected to ``fixed_key`` (only
        ``fixed_key`` when nothing is); and what the placement test needs.
    """
    fixed_value = fixed_value or (np.eye(2), np.zeros(3))
    keys, index, M, b_z = _joint_form(problems, fixed_key)
    if len(keys) == 1:
        return JointSolution({fixed_key: fixed_value}, index, np.zeros((0, 0)), np.zeros(1))
    n = len(keys)
    # gauge-free, as the centralized window (Liu et al. 2024 eq. (14)-(18)), then moved onto the fixed value
    Q = reduce_rotations(M, n)
    res = solve_low_rank(Q)
    position = recover_positions(M, res.theta, b_z)
    f = index[fixed_key]
    d = _yaw(fixed_value[0]) - res.theta[f]
    Rd = rot2(d)
    theta = res.theta + d
    p_fix = np.asarray(fixed_value[1], float)
    position[:, :2] = (position[:, :2] - position[f, :2]) @ Rd.T + p_fix[:2]
    position[:, 2] += p_fix[2] - position[f, 2]
    R = rot2(theta)
    return JointSolution({k: (R[i], position[i]) for i, k in enumerate(keys)}, index, Q, theta)
