"""Rotation elimination, the SDP relaxation, its low-rank solution, certificate and rounding.

Given the window's xy quadratic form ``M`` over ``[P_xy | R2_1..R2_m]`` (:mod:`decentral.window`):

1. positions are eliminated by the Schur complement with the pseudo-inverse (Liu et al. 2024 after
   eq. (14)): ``Q = M_RR - M_pR^T M_pp^+ M_pR``;
2. the rotations solve the relaxation ``min tr(Q Z)`` over ``Z ⪰ 0`` with identity 2x2 diagonal
   blocks (eq. (15a)-(15b); eq. (15c) reduces the 3x3 blocks to their free 2x2 parts exactly, since
   the fixed z entries only add a constant). We add one more convex constraint that every pair of
   yaw rotations satisfies: each free block ``Z_ij = R_i^T R_j`` commutes with rotations, i.e. has the
   form ``[[c, -s], [s, c]]``. Without it the relaxation is one of O(2), not SO(2), and it is not tight
   whenever a mirror image of the scene fits (a straight-line assembly moving along its axis is
   enough: measured in ``tests/decentral/test_relaxation.py``). With it the relaxation is the
   Hermitian one, ``min Re tr(W Z)`` over ``Z ⪰ 0`` complex with unit diagonal, where
   ``W_ij = tr(Q_ij) + i (Q_ij[0,1] - Q_ij[1,0])``;
3. the solution is rounded to SO(2) per block (eq. (16)-(17)) and positions follow in closed form
   (eq. (18)).

Two solvers give the same optimum:

* :class:`SdpSolver` — the reference: the dual SDP ``max sum(λ)`` s.t. ``W - diag(λ) ⪰ 0``
  built once per size in cvxpy over a :class:`cvxpy.Parameter` and re-solved with Clarabel (its
  chordal decomposition is what makes the dual form fast, see FINDINGS); ``Z`` is the dual of
  the PSD constraint.
* :func:`solve_low_rank` — Burer-Monteiro at rank 2 restricted to rotations [1]_: a globalized
  Newton method on the angles, followed by the optimality certificate
  ``S = W - Diag(Re(conj(z) ∘ W z)) ⪰ 0`` (SE-Sync's ``Q - SymBlockDiag(Q Y^T Y)`` in Hermitian form);
  when the certificate fails it falls back to the SDP.
* :func:`solve_literal_primal` — Liu et al.'s P3 exactly as printed (3m x 3m primal, O(2) blocks),
  the naive reference of the window benchmark. :func:`certificate_o2` tells whether that weaker
  relaxation is tight at a given solution.

References
----------
.. [1] D. M. Rosen, L. Carlone, A. S. Bandeira, J. J. Leonard, "SE-Sync: A certifiably correct
   algorithm for synchronization over the special Euclidean group", IJRR 38(2-3), 2019.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from decentral.errors import SolverError
from decentral.geometry import project_so2, rot2

__all__ = [
    "RelaxationResult",
    "reduce_rotations",
    "recover_positions",
    "certificate",
    "certificate_o2",
    "round_gram",
    "solve_low_rank",
    "SdpSolver",
    "solve_literal_primal",
    "solve_relaxation",
    "yaw_hessian",
]

#: certificate tolerance, relative to the largest |eigenvalue| of Q
CERT_TOL = 1e-7


@dataclass(frozen=True)
class RelaxationResult:
    """Rotations of one window and how they were found.

    Attributes
    ----------
    theta : ndarray, shape (m,)
        Yaw of each variable, in one arbitrary common gauge.
    cost : float
        ``tr(Q Z)`` at the rounded rotations.
    certified : bool
        True when the certificate proves the rounded rotations globally optimal for the relaxation
        (and hence for the original problem).
    min_eig : float
        Smallest eigenvalue of the certificate matrix ``S`` (>= -tol when certified).
    solver : str
        ``"low-rank"``, ``"sdp"`` or ``"low-rank+sdp"`` (fallback after a failed certificate).
    status : str
        ``"optimal"``, or a solver status the caller can act on.
    iterations : int
        Newton iterations of the low-rank solve (0 for the SDP).
    seconds : float
        Wall time of the solve.
    """

    theta: np.ndarray
    cost: float
    certified: bool
    min_eig: float
    solver: str
    status: str
    iterations: int
    seconds: float

    @property
    def rotations(self) -> np.ndarray:
        """(m, 2, 2) SO(2) matrices."""
        return rot2(self.theta)


def _anchored_pinv_apply(L: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``L^+ B`` for a connected weighted Laplacian ``L`` (m, m) and ``B`` with columns ⟂ 1.

    Anchoring the first variable gives a generalized inverse; for right-hand sides orthogonal to
    the null space (all ones) it yields the minimum-norm solution after removing the mean.
    """
    m = L.shape[0]
    X = np.zeros((m,) + B.shape[1:])
    if m > 1:
        try:
            factor = scipy.linalg.cho_factor(L[1:, 1:], check_finite=False)
            X[1:] = scipy.linalg.cho_solve(factor, B[1:], check_finite=False)
        except np.linalg.LinAlgError:  # numerically semidefinite: weights spanning too many orders of magnitude
            X[1:] = scipy.linalg.lstsq(L[1:, 1:], B[1:], check_finite=False)[0]
    return X - X.mean(axis=0)


def reduce_rotations(M: np.ndarray, m: int) -> np.ndarray:
    """Eliminate positions: ``Q = M_RR - M_pR^T M_pp^+ M_pR`` (2m, 2m), Liu et al. 2024 after eq. (14)."""
    M_pp, M_pR, M_RR = M[:m, :m], M[:m, m:], M[m:, m:]
    Q = M_RR - M_pR.T @ _anchored_pinv_apply(M_pp, M_pR)
    return 0.5 * (Q + Q.T)


def recover_positions(M: np.ndarray, theta: np.ndarray, b_z: np.ndarray) -> np.ndarray:
    """Positions (m, 3) in closed form given the yaws (Liu et al. 2024 eq. (18)) plus the z solve.

    .. math:: P_{xy}^* = -\\underline{\\mathfrak R}^* M_{pR}^T M_{pp}^+, \\qquad M_{pp} p_z = b_z
    """
    m = len(theta)
    Y = rot2(theta).transpose(1, 0, 2).reshape(2, 2 * m)  # [R2_1 .. R2_m], (2, 2m)
    M_pp, M_pR = M[:m, :m], M[:m, m:]
    rhs = np.column_stack([-(M_pR @ Y.T), b_z])  # (m, 3); columns sum to zero
    return _anchored_pinv_apply(M_pp, rhs)


def _stack(theta: np.ndarray) -> np.ndarray:
    return rot2(theta).transpose(1, 0, 2).reshape(2, 2 * len(theta))


def certificate(Q: np.ndarray, theta: np.ndarray) -> float:
    """Smallest eigenvalue of the certificate ``S = W - Diag(Re(conj(z) ∘ W z))`` at ``theta``.

    ``S ⪰ 0`` (with ``S z = 0`` at a critical point) proves ``z z^H`` optimal for the SO(2)
    relaxation, the Hermitian form of SE-Sync's ``S = Q - SymBlockDiag(Q Y^T Y)`` [1]_ (Theorem 7).
    Dense ``eigvalsh`` is exact here; see FINDINGS on why a shift-invert solve near zero is not a
    valid test.
    """
    W = _hermitian_form(Q)
    z = np.exp(1j * np.asarray(theta))
    S = W - np.diag((np.conj(z) * (W @ z)).real)
    return float(np.linalg.eigvalsh(S)[0])  # LAPACK heevd; scipy's default evr driver was 100x slower here


def certificate_o2(Q: np.ndarray, theta: np.ndarray) -> float:
    """Smallest eigenvalue of SE-Sync's ``S = Q - SymBlockDiag(Q Y^T Y)`` (2m, 2m) at ``theta``.

    Non-negative when the rotations are optimal even for Liu et al.'s literal P3, which relaxes O(2).
    """
    m = len(theta)
    Y = _stack(theta)
    QY = Q @ Y.T @ Y
    S = Q.copy()
    for i in range(m):
        block = QY[2 * i : 2 * i + 2, 2 * i : 2 * i + 2]
        S[2 * i : 2 * i + 2, 2 * i : 2 * i + 2] -= 0.5 * (block + block.T)
    return float(np.linalg.eigvalsh(S)[0])  # LAPACK heevd; scipy's default evr driver was 100x slower here


def _hermitian_form(Q: np.ndarray) -> np.ndarray:
    """Complex ``W`` (m, m) with ``tr(Y Q Y^T) = z^H W z`` for rotations ``Y``, ``z_i = e^{i theta_i}``.

    Only the rotation-commuting part of each 2x2 block counts on SO(2):
    ``W_ij = tr(Q_ij) + i (Q_ij[0,1] - Q_ij[1,0])``.
    """
    m = Q.shape[0] // 2
    B = Q.reshape(m, 2, m, 2)
    return (B[:, 0, :, 0] + B[:, 1, :, 1]) + 1j * (B[:, 0, :, 1] - B[:, 1, :, 0])


def _scale(W: np.ndarray) -> float:
    """An upper bound on the spectral radius of ``W`` (its infinity norm), for relative tolerances."""
    return max(float(np.abs(W).sum(axis=1).max()), 1e-300)


def _spectral_init(W: np.ndarray) -> np.ndarray:
    """Angles from the eigenvector of ``W``'s smallest eigenvalue, entries rounded to unit modulus."""
    _, vecs = np.linalg.eigh(W)
    v = vecs[:, 0]
    small = np.abs(v) < 1e-12
    v = np.where(small, 1.0, v)
    return np.angle(v * np.conj(v[0]) / max(abs(v[0]), 1e-300))


def yaw_hessian(Q: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Hessian (m, m) of ``f(theta) = tr(Y(theta) Q Y(theta)^T)`` in the angles.

    Its null space always holds the global gauge (all ones); any other null direction is a yaw
    the measurements do not determine.
    """
    W = _hermitian_form(Q)
    z = np.exp(1j * theta)
    A = 2.0 * (np.conj(z)[:, None] * W * z[None, :]).real
    H = A.copy()
    np.fill_diagonal(H, 0.0)
    H[np.diag_indices_from(H)] = -H.sum(axis=1)
    return H


def _newton(W: np.ndarray, theta: np.ndarray, max_iter: int = 100, gtol: float = 1e-11):
    """Minimize ``z^H W z`` over ``z = e^{i theta}`` by saddle-free Newton with backtracking.

    Stops when the gradient is at round-off level or the Newton decrement predicts a decrease
    below round-off of the cost (the quadratic model can promise nothing more).
    """
    scale = _scale(W)

    def value(th):
        z = np.exp(1j * th)
        return float((np.conj(z) @ (W @ z)).real)

    f = value(theta)
    for it in range(1, max_iter + 1):
        z = np.exp(1j * theta)
        s = np.conj(z) * (W @ z)
        g = 2.0 * s.imag
        if np.abs(g).max() <= gtol * scale:
            return theta, f, it - 1
        A = 2.0 * (np.conj(z)[:, None] * W * z[None, :]).real
        np.fill_diagonal(A, 0.0)
        H = A - np.diag(A.sum(axis=1))
        lam, V = np.linalg.eigh(H)
        step = -V @ ((V.T @ g) / np.maximum(np.abs(lam), 1e-10 * scale))
        slope = float(g @ step)
        if -slope <= 1e-13 * (abs(f) + scale):
            return theta, f, it - 1
        t = 1.0
        while t > 1e-10:
            trial = theta + t * step
            f_trial = value(trial)
            if f_trial <= f + 1e-4 * t * slope:
                break
            t *= 0.5
        else:
            return theta, f, it
        theta, f = trial, f_trial
    return theta, f, max_iter


def solve_low_rank(Q: np.ndarray, theta0: np.ndarray | None = None, *, fallback: bool = True) -> RelaxationResult:
    """Rank-2 Burer-Monteiro solve on SO(2)^m with its certificate; SDP fallback if it fails.

    Parameters
    ----------
    Q : ndarray, shape (2m, 2m)
        Reduced rotation cost.
    theta0 : ndarray, shape (m,), optional
        Warm start (e.g. the previous window's yaws); the spectral initialization is tried too when
        the warm start does not certify.
    fallback : bool
        Solve the SDP (:class:`SdpSolver`) when no low-rank point certifies.
    """
    start = time.perf_counter()
    W = _hermitian_form(Q)
    tol = CERT_TOL * _scale(W)
    best = None
    inits = ([theta0] if theta0 is not None else []) + [None]
    iters = 0
    for init in inits:
        th0 = _spectral_init(W) if init is None else np.asarray(init, dtype=float)
        theta, f, it = _newton(W, th0)
        iters += it
        lam = certificate(Q, theta)
        if best is None or f < best[1]:
            best = (theta, f, lam)
        if lam >= -tol:
            return RelaxationResult(theta, f, True, lam, "low-rank", "optimal", iters, time.perf_counter() - start)
    theta, f, lam = best
    if not fallback:
        return RelaxationResult(theta, f, False, lam, "low-rank", "uncertified", iters, time.perf_counter() - start)
    sdp = SdpSolver.shared(Q.shape[0] // 2).solve(Q)
    if sdp.cost <= f:
        return RelaxationResult(
            sdp.theta, sdp.cost, sdp.certified, sdp.min_eig, "low-rank+sdp", sdp.status, iters,
            time.perf_counter() - start,
        )
    return RelaxationResult(theta, f, False, lam, "low-rank+sdp", "uncertified", iters, time.perf_counter() - start)


def round_gram(Z: np.ndarray) -> np.ndarray:
    """Angles (m,) from a PSD Gram matrix ``Z`` (2m, 2m): rank-2 factor then eq. (17) per block.

    The rank-2 factor ``Y = sqrt(Λ_2) V_2^T`` is determined up to O(2); the reflection that puts most
    blocks in SO(2) is chosen before projecting, as SE-Sync's rounding does.
    """
    m = Z.shape[0] // 2
    lam, V = np.linalg.eigh(0.5 * (Z + Z.T))
    Y = (V[:, -2:] * np.sqrt(np.maximum(lam[-2:], 0.0))).T  # (2, 2m)
    blocks = Y.reshape(2, m, 2).transpose(1, 0, 2)  # (m, 2, 2)
    if np.sum(np.linalg.det(blocks) > 0) < m / 2:
        blocks = blocks * np.array([1.0, -1.0])[None, :, None]
    R = project_so2(blocks)  # Liu et al. 2024 eq. (17)
    return np.arctan2(R[:, 1, 0], R[:, 0, 0])


def _embed(Z: np.ndarray) -> np.ndarray:
    """Real (2m, 2m) Gram form of a Hermitian (m, m) ``Z``: block ``ij`` is ``[[Re, Im], [-Im, Re]]``.

    With ``Z = z z^H``, ``z_i = e^{i theta_i}``, block ``ij`` is ``R_i^T R_j = R(theta_j - theta_i)``.
    """
    m = Z.shape[0]
    out = np.empty((m, 2, m, 2))
    out[:, 0, :, 0] = out[:, 1, :, 1] = Z.real
    out[:, 1, :, 0] = -Z.imag
    out[:, 0, :, 1] = Z.imag
    return out.reshape(2 * m, 2 * m)


class SdpSolver:
    r"""The reference solver: the SO(2) relaxation's dual in cvxpy, built once per size, by Clarabel.

    .. math:: \max_{\lambda \in \mathbb{R}^m} \textstyle\sum_i \lambda_i \;\text{s.t.}\; W - \operatorname{diag}(\lambda) \succeq 0

    posed in its real form (the Hermitian PSD constraint on ``W`` is the real PSD constraint on its
    interleaved 2m x 2m embedding, :func:`_embed`) so that Clarabel's chordal decomposition sees the
    window's block sparsity; cvxpy's own complex-to-real reduction hides it and was 10-100x slower.
    The primal ``Z`` (eq. (15a)-(15c) with commuting blocks) is the dual variable of the PSD
    constraint; it is rounded by eq. (17).
    """

    _cache: dict[int, "SdpSolver"] = {}

    def __init__(self, m: int):
        import cvxpy as cp
        import scipy.sparse as sp

        self.m = m
        self.W = cp.Parameter((2 * m, 2 * m), symmetric=True)
        self.lam = cp.Variable(m)
        expand = sp.csr_matrix((np.ones(2 * m), (np.arange(2 * m), np.repeat(np.arange(m), 2))), shape=(2 * m, m))
        self.constraint = self.W - cp.diag(expand @ self.lam) >> 0
        self.problem = cp.Problem(cp.Maximize(cp.sum(self.lam)), [self.constraint])
        if not self.problem.is_dcp(dpp=True):  # pragma: no cover - a construction bug, not an input error
            raise SolverError("the relaxation's dual is not DPP")

    @classmethod
    def shared(cls, m: int) -> "SdpSolver":
        """The cached solver for ``m`` rotations (problems are built once and re-solved)."""
        if m not in cls._cache:
            cls._cache[m] = cls(m)
        return cls._cache[m]

    def solve(self, Q: np.ndarray) -> RelaxationResult:
        """Solve the relaxation for ``Q`` (2m, 2m), round (eq. (17)) and certify."""
        import warnings

        import cvxpy as cp

        start = time.perf_counter()
        W = _hermitian_form(0.5 * (Q + Q.T))
        # the optimal Z does not depend on the cost's scale; unit scale keeps Clarabel well conditioned
        Wr = _embed(0.5 * (W + W.conj().T) / _scale(W))
        self.W.value = 0.5 * (Wr + Wr.T)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)  # inaccuracy is reported in the status
                self.problem.solve(solver=cp.CLARABEL, verbose=False)
            status = self.problem.status
        except cp.error.SolverError:
            status = "solver_error"
        if status not in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE) or self.constraint.dual_value is None:
            return RelaxationResult(np.zeros(self.m), float("inf"), False, -np.inf, "sdp", str(status), 0,
                                    time.perf_counter() - start)
        theta = round_gram(np.asarray(self.constraint.dual_value))
        z = np.exp(1j * theta)
        cost = float((np.conj(z) @ W @ z).real)
        lam = certificate(Q, theta)
        # certified when the rounded point meets the bound (tight relaxation); a looser tolerance than
        # the low-rank path since interior-point duals are accurate to ~1e-8 relative
        certified = lam >= -100 * CERT_TOL * _scale(W)
        return RelaxationResult(theta, cost, bool(certified), lam, "sdp",
                                "optimal" if status == cp.OPTIMAL else "optimal_inaccurate", 0,
                                time.perf_counter() - start)


def solve_literal_primal(Q: np.ndarray) -> RelaxationResult:
    """Liu et al. 2024 P3 exactly as written: a fresh cvxpy problem over the 3m x 3m primal ``Z``.

    Constraints (15b) (identity diagonal blocks) and (15c) (the fixed z entries of every block);
    the 2x2 free parts of ``Q`` are embedded in 3x3 blocks. This is the naive reference of the
    window benchmark; it is slow (a dense PSD block in the KKT system, see FINDINGS).
    """
    import cvxpy as cp

    start = time.perf_counter()
    m = Q.shape[0] // 2
    n = 3 * m
    free = np.array([3 * i + a for i in range(m) for a in (0, 1)])
    Q3 = np.zeros((n, n))
    Q3[np.ix_(free, free)] = Q
    Z = cp.Variable((n, n), PSD=True)
    cons = []
    for i in range(m):
        cons.append(Z[3 * i : 3 * i + 3, 3 * i : 3 * i + 3] == np.eye(3))  # (15b)
        for j in range(i + 1, m):
            cons += [Z[3 * i + 2, 3 * j : 3 * j + 2] == 0, Z[3 * i : 3 * i + 2, 3 * j + 2] == 0,
                     Z[3 * i + 2, 3 * j + 2] == 1]  # (15c)
    problem = cp.Problem(cp.Minimize(cp.trace(Q3 @ Z)), cons)
    try:
        problem.solve(solver=cp.CLARABEL, verbose=False)
    except cp.error.SolverError as err:
        raise SolverError(f"Clarabel failed on the literal relaxation: {err}") from None
    if Z.value is None:
        return RelaxationResult(np.zeros(m), float("inf"), False, -np.inf, "literal", str(problem.status), 0,
                                time.perf_counter() - start)
    theta = round_gram(Z.value[np.ix_(free, free)])
    Y = _stack(theta)
    return RelaxationResult(theta, float(np.trace(Y @ Q @ Y.T)), False, certificate_o2(Q, theta), "literal",
                            str(problem.status), 0, time.perf_counter() - start)


def solve_relaxation(Q: np.ndarray, solver: str = "low-rank", theta0: np.ndarray | None = None) -> RelaxationResult:
    """Dispatch to ``"low-rank"`` (default, certified, SDP fallback) or ``"sdp"`` (reference)."""
    if solver == "low-rank":
        return solve_low_rank(Q, theta0)
    if solver == "sdp":
        return SdpSolver.shared(Q.shape[0] // 2).solve(Q)
    raise ValueError(f"unknown solver {solver!r}; expected 'low-rank' or 'sdp'")
