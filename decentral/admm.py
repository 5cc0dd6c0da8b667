r"""Consensus-ADMM over per-pair relaxed subproblems: the math every assembly agent runs.

Splitting
---------
A window (steps ``k-K+1 .. k``) has one pose variable ``x_{a,j} = (R_{a,j}, p_{a,j})`` per assembly
``a`` and step ``j`` (yaw ``R`` in SO(2), ``p`` in R^3). The joint cost of
:mod:`decentral.window` is a sum of visual factors (seed 000 eq. (4)) and odometry factors
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

with separate penalties ``rho_R`` (rotation blocks, Frobenius norm) and ``rho_p`` (positions, metres)
per pair, adapted by residual balancing [1]_ §3.4.1 (``r > mu s``: ``rho *= tau``, ``u /= tau``;
``s > mu r``: the converse). The primal residual of pair ``e`` is ``r_e = ||y_e - z_e||``, its dual
residual ``s_e = rho_e ||z_e^{t+1} - z_e^t||``; ADMM stops when the primal residual and the consensus
change are below absolute tolerances. With over-relaxation [1]_ §3.4.3 the consensus and dual updates
use ``y_hat = alpha y + (1 - alpha) z`` in place of ``y``.

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
remain are kept; a new step's consensus pose is the previous one moved by the odometry.

References
----------
.. [1] S. Boyd, N. Parikh, E. Chu, B. Peleato, J. Eckstein, "Distributed optimization and statistical
   learning via the alternating direction method of multipliers", Foundations and Trends in Machine
   Learning 3(1), 2011.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from decentral.errors import InputError
from decentral.geometry import rot2
from decentral.relaxation import solve_low_rank

__all__ = [
    "AdmmConfig",
    "LocalProblem",
    "ProxSolution",
    "quadratic_form",
    "solve_prox",
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
        Initial penalties relative to each pair's mean curvature (diagonal of its quadratic form).
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

    The defaults were picked on the 6-assembly ring (K = 5, 6 steps): rounds to converge summed over
    the steps 531 (rho0 0.3, mu 10, alpha 1), 396 (mu 3), 347 (alpha 1.5), 282 (rho0 1, mu 3,
    alpha 1.5), 287 (alpha 1.8), 315 (rho0 3).
    """

    rho0: float = 1.0
    mu: float = 3.0
    tau: float = 2.0
    rho_span: float = 1e4
    eps_rot: float = 3e-5
    eps_pos: float = 3e-5
    balance_every: int = 1
    alpha: float = 1.5

    def __post_init__(self) -> None:
        if not (self.rho0 > 0 and self.mu > 1 and self.tau > 1 and self.rho_span >= 1):
            raise InputError("need rho0 > 0, mu > 1, tau > 1, rho_span >= 1", field="admm")
        if not (self.eps_rot > 0 and self.eps_pos > 0):
            raise InputError("tolerances must be positive", field="admm")
        if not (isinstance(self.balance_every, int) and self.balance_every >= 1):
            raise InputError("balance_every must be an integer >= 1", field="admm")
        if not 0 < self.alpha < 2:
            raise InputError("alpha must be in (0, 2)", field="admm")


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
    """Sum of weighted factor outer products over ``keys`` (seed 000 eq. (5), (8), (11)).

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
        # seed 000 eq. (4): e = R_a q + p_a - p_o - R_o t
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
        # seed 000 eq. (7), position: e = p_u - p_v - R_v dp
        np.add.at(C, (r, iu), 1.0)
        np.add.at(C, (r, iv), -1.0)
        np.add.at(C, (r, n + 2 * iv), -dp[:, 0])
        np.add.at(C, (r, n + 2 * iv + 1), -dp[:, 1])
        rows_C.append(C), rows_w.append(np.asarray(w_p, float)), rows_s.append(-dp[:, 2])
        # seed 000 eq. (7), rotation: ||R_u - R_v R̂||_F^2
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


def solve_prox(problem: LocalProblem, R_bar: np.ndarray, p_bar: np.ndarray, rho_R: np.ndarray,
               rho_p: np.ndarray, fixed: dict | None = None, theta0: np.ndarray | None = None) -> ProxSolution:
    r"""Minimize ``cost(x) + sum_i rho_R_i/2 ||R_i - R_bar_i||^2 + rho_p_i/2 ||p_i - p_bar_i||^2``.

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
    n = problem.n
    fixed = fixed or {}
    rho_R = np.asarray(rho_R, float)
    rho_p = np.asarray(rho_p, float)
    Mp = problem.M.copy()
    Mp[np.arange(n), np.arange(n)] += 0.5 * rho_p
    # cost_xy = tr(X Mp X^T) + 2 sum(L * X); the prox is linear in R since ||R||_F^2 = 2 on SO(2)
    L = np.zeros((2, 3 * n))
    L[:, :n] = -0.5 * rho_p * p_bar[:, :2].T
    L[:, n:] = -0.5 * np.repeat(rho_R, 2) * np.asarray(R_bar).transpose(1, 0, 2).reshape(2, 2 * n)
    Az = problem.M[:n, :n] + np.diag(0.5 * rho_p)
    bz = problem.b_z + 0.5 * rho_p * p_bar[:, 2]
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
    Q = C - B.T @ AiB  # positions eliminated (Schur complement, cf. seed 000 after eq. (14))
    Q = 0.5 * (Q + Q.T)
    G = LR - Lp @ AiB  # linear term in the rotations: 2 sum_i tr(R_i^T G_i)
    gamma = (G[0, 0::2] + G[1, 1::2]) + 1j * (G[1, 0::2] - G[0, 1::2])
    W = np.zeros((nf + 1, nf + 1), complex)
    W[1:, 1:] = _hermitian(Q)
    W[1:, 0] = gamma  # homogenizing rotation z_0: 2 Re(gamma^H z) = z~^H [[0, gamma^H], [gamma, W]] z~
    W[0, 1:] = np.conj(gamma)
    th0 = None if theta0 is None else np.concatenate([[0.0], np.asarray(theta0, float)[free]])
    res = solve_low_rank(_real_form(W), th0)
    th = res.theta[1:] - res.theta[0]  # divide out the homogenizing rotation
    th = np.arctan2(np.sin(th), np.cos(th))
    Y = rot2(th).transpose(1, 0, 2).reshape(2, 2 * nf)
    P = -np.linalg.solve(A, B @ Y.T + Lp.T)  # seed 000 eq. (18) with the prox terms, (nf, 2)
    pz = np.linalg.solve(Az_f, bz_f)
    theta[free] = th
    position[free, :2] = P
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


class PairState:
    """ADMM state of one directed observing pair ``observer -> target``, kept by the observer's agent.

    The pair's local copies ``y`` cover the window steps at which it has visual factors. Call
    :meth:`set_problem` whenever the window or the factors change (copies and duals of the keys that
    remain are kept: the warm start), then :meth:`iterate` once per ADMM round with the newest
    consensus values.
    """

    def __init__(self, observer: str, target: str, config: AdmmConfig):
        self.observer, self.target, self.config = observer, target, config
        self.problem: LocalProblem | None = None
        self.y: dict = {}  # key -> Pose2 (local copy)
        self.u: dict = {}  # key -> Pose2-shaped scaled dual (2x2, 3)
        self.z_used: dict = {}  # key -> Pose2 consensus used in the last dual update
        self.rho_R = self.rho_p = 0.0
        self.rho_scale = 1.0
        self.r_R = self.r_p = self.s_R = self.s_p = np.inf
        self.iterations = 0
        self.certified = True
        self.live_prev: set = set()
        self.y_hat: dict = {}

    def set_problem(self, problem: LocalProblem) -> None:
        """Install the pair's factor cost for the current window, keeping state of surviving keys."""
        keep = set(problem.keys)
        self.y = {k: v for k, v in self.y.items() if k in keep}
        self.u = {k: v for k, v in self.u.items() if k in keep}
        self.z_used = {k: v for k, v in self.z_used.items() if k in keep}
        self.problem = problem
        n = problem.n
        scale_p = float(np.trace(problem.M[:n, :n])) / max(n, 1)
        scale_R = float(np.trace(problem.M[n:, n:])) / max(2 * n, 1)
        if self.rho_R == 0.0 and scale_R > 0:
            self.rho_R = self.config.rho0 * scale_R
            self.rho_p = self.config.rho0 * scale_p
            span = self.config.rho_span
            self.rho_scale = 1.0
            self.s_R = self.s_p = np.inf

    @property
    def residuals(self) -> tuple[float, float, float, float]:
        """``(r_R, r_p, s_R, s_p)`` of the last iteration."""
        return self.r_R, self.r_p, self.s_R, self.s_p

    def converged(self) -> bool:
        """Primal residual and consensus change (dual residual / rho) below the tolerances."""
        c = self.config
        return (max(self.r_R, self.s_R / max(self.rho_R, 1e-300)) <= c.eps_rot
                and max(self.r_p, self.s_p / max(self.rho_p, 1e-300)) <= c.eps_pos)

    def iterate(self, z: dict, ready: dict) -> dict:
        """One ADMM iteration: dual update with ``z``, penalty balancing, then the copy update.

        Parameters
        ----------
        z : dict
            key -> consensus value ``Pose2`` for every key whose assembly's consensus is known.
        ready : dict
            assembly name -> whether its consensus is in the pinned gauge (initialized).

        Returns
        -------
        dict
            key -> ``(y + u)`` as ``Pose2``: what the owning assembly averages.
        """
        prob = self.problem
        if prob is None or prob.n == 0:
            return {}
        keys = prob.keys
        live = [k for k in keys if ready.get(k[0], False) and k in z]
        # dual update u += y - z and residuals (Boyd §3.3): only for copies that were live in the last
        # copy update too (a copy made before its assembly joined the gauge says nothing about z)
        both = [k for k in live if k in self.live_prev and k in self.y_hat]
        if both:
            rR = rp = sR = sp = 0.0
            for k in both:
                zR, zp = z[k]
                yR, yp = self.y_hat[k]
                uR, up = self.u.get(k, (np.zeros((2, 2)), np.zeros(3)))
                self.u[k] = (uR + yR - zR, up + yp - zp)
                rR += float(np.sum((yR - zR) ** 2))
                rp += float(np.sum((yp - zp) ** 2))
                if k in self.z_used:
                    sR += float(np.sum((zR - self.z_used[k][0]) ** 2))
                    sp += float(np.sum((zp - self.z_used[k][1]) ** 2))
                else:
                    sR = sp = np.inf
            self.r_R, self.r_p = np.sqrt(rR), np.sqrt(rp)
            self.s_R, self.s_p = self.rho_R * np.sqrt(sR), self.rho_p * np.sqrt(sp)
            if (self.iterations % self.config.balance_every == 0 and np.isfinite(sR) and sR + sp > 0):
                # one factor for both penalties, residuals measured in the penalty metric so that
                # rotations (unitless) and positions (metres) compare
                r_w = np.sqrt(self.rho_R * rR + self.rho_p * rp)
                s_w = np.sqrt(self.rho_R * sR + self.rho_p * sp)
                span = self.config.rho_span
                new = balance_penalty(self.rho_scale, r_w, s_w, self.config, 1.0 / span, span)
                factor = new / self.rho_scale
                self.rho_scale = new
                if factor != 1.0:
                    for k in self.u:
                        uR, up = self.u[k]
                        self.u[k] = (uR / factor, up / factor)
                    self.rho_R *= factor
                    self.rho_p *= factor
        else:
            self.r_R = self.r_p = self.s_R = self.s_p = np.inf
        for k in live:
            self.z_used[k] = z[k]
        self.live_prev = set(live)
        # copy update: prox towards z - u (live keys) or a vanishing pull to the last copy (others)
        n = prob.n
        R_bar = np.zeros((n, 2, 2))
        p_bar = np.zeros((n, 3))
        rho_R = np.zeros(n)
        rho_p = np.zeros(n)
        theta0 = np.zeros(n)
        tiny = 1e-9
        for i, k in enumerate(keys):
            if k in live:
                zR, zp = z[k]
                uR, up = self.u.get(k, (np.zeros((2, 2)), np.zeros(3)))
                R_bar[i], p_bar[i] = zR - uR, zp - up
                rho_R[i], rho_p[i] = self.rho_R, self.rho_p
                theta0[i] = _yaw(self.y[k][0]) if k in self.y else _yaw(zR)
            else:
                prev = self.y.get(k) or z.get(k) or (np.eye(2), np.zeros(3))
                R_bar[i], p_bar[i] = prev
                rho_R[i], rho_p[i] = tiny * self.rho_R, tiny * self.rho_p
                theta0[i] = _yaw(prev[0])
        sol = solve_prox(prob, R_bar, p_bar, rho_R, rho_p, theta0=theta0)
        self.certified = sol.certified
        R = sol.rotations
        self.y = {k: (R[i], sol.position[i]) for i, k in enumerate(keys)}
        # over-relaxation (Boyd §3.4.3): y_hat = alpha y + (1 - alpha) z
        a = self.config.alpha
        self.y_hat = {k: ((a * y[0] + (1 - a) * z[k][0], a * y[1] + (1 - a) * z[k][1]) if k in live else y)
                      for k, y in self.y.items()}
        self.iterations += 1
        out = {}
        for k in keys:
            uR, up = self.u.get(k, (np.zeros((2, 2)), np.zeros(3)))
            if k not in live:
                uR, up = np.zeros((2, 2)), np.zeros(3)
            out[k] = (self.y_hat[k][0] + uR, self.y_hat[k][1] + up)
        return out


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
        self.pin: tuple[int, float, np.ndarray] | None = None

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

    def update(self, contributions: list[tuple[dict, float, float]]) -> bool:
        """Consensus update from pair contributions ``(step -> (y + u), rho_R, rho_p)``.

        Returns whether the consensus changed (False when nothing usable arrived yet).
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
        acc_R = np.zeros((n, 2, 2))
        acc_p = np.zeros((n, 3))
        rho_R = np.zeros(n)
        rho_p = np.zeros(n)
        scale_R = scale_p = 0.0
        for values, rR, rp in contributions:
            scale_R, scale_p = max(scale_R, rR), max(scale_p, rp)
            for k, (VR, Vp) in values.items():
                if k in idx:
                    i = idx[k]
                    acc_R[i] += rR * VR
                    acc_p[i] += rp * Vp
                    rho_R[i] += rR
                    rho_p[i] += rp
        # a vanishing pull to the current value keeps steps without factors well posed
        tiny_R = 1e-9 * max(scale_R, float(np.trace(prob.M[n:, n:])) / (2 * n), 1e-12)
        tiny_p = 1e-9 * max(scale_p, float(np.trace(prob.M[:n, :n])) / n, 1e-12)
        cur_R = np.array([self.z[k][0] for k in steps])
        cur_p = np.array([self.z[k][1] for k in steps])
        acc_R += tiny_R * cur_R
        acc_p += tiny_p * cur_p
        rho_R += tiny_R
        rho_p += tiny_p
        R_bar = acc_R / rho_R[:, None, None]
        p_bar = acc_p / rho_p[:, None]
        fixed = {}
        if self.pinned and self.pin is not None and self.pin[0] in idx:
            fixed[idx[self.pin[0]]] = (self.pin[1], self.pin[2])
        theta0 = np.array([_yaw(R) for R in cur_R])
        sol = solve_prox(prob, R_bar, p_bar, rho_R, rho_p, fixed=fixed, theta0=theta0)
        R = sol.rotations
        change = 0.0
        for i, k in enumerate(steps):
            change = max(change, float(np.abs(R[i] - cur_R[i]).max()), float(np.abs(sol.position[i] - cur_p[i]).max()))
            self.z[k] = (R[i], sol.position[i])
        self.change = change
        self.ready = True
        return True

