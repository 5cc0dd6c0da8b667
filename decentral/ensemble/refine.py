"""Refinement of an ensemble estimate to the maximum likelihood (Funiak et al. 2008 eq. 3, Algorithm 1 line 11).

Four methods, all on the sparse structure of the contact graph and fully vectorized:

``"alternating"`` (the default of :class:`RefineConfig`)
    Exact block-coordinate descent: for fixed centres the best orientations are a closed-form
    Kabsch fit per module; for fixed orientations the best centres solve one linear system whose
    matrix is the graph Laplacian, which does not depend on the orientations, so it is factorized
    once per call and every iteration costs two triangular solves. The sweeps are accelerated by
    Anderson mixing on the centres, with a safeguard that falls back to the plain sweep whenever the
    accelerated point does not lower the likelihood, so the cost never increases.
``"lm"``
    Levenberg-Marquardt on the full Jacobian (positions and orientation increments), one sparse LU
    per iteration: quadratic convergence, but the factorization of the coupled system fills in
    about 27 times more than the Laplacian's, so it is only used for small problems.
``"lbfgs"``
    The same reduced problem as ``"alternating"`` — the orientations are fitted in closed form to
    the centres, so the likelihood becomes a function F(c) of the centres alone, whose gradient is
    the position gradient at the fitted orientations — minimized by limited-memory BFGS whose
    initial inverse Hessian is the exact one of the position block, 4 L^-1 (so its first step
    is the plain alternating sweep), with a backtracking (Armijo) line search. Its curvature pairs
    learn the soft collective modes (a 3D solid twisting about the thin rods that join its
    chambers) that make Anderson-mixed sweeps advance in plateaus. One Laplacian solve and
    usually one orientation fit per iteration. With ``RefineConfig.coarse_size`` the initial
    inverse Hessian is two-level (:mod:`decentral.ensemble.coarse`): 4 L^-1 plus the rigid motions
    of clusters, which those soft modes are made of. The default of Algorithm 1's
    :class:`~decentral.ensemble.HierarchyConfig` (two-level at the top).
``"pcg"``
    Preconditioned nonlinear conjugate gradient, the refiner of Funiak et al. 2008 §VI-B/E: O(E) per
    iteration, no factorization, so it undoes errors far from where they are corrected only slowly
    (Fig. 3c); kept for the faithful accuracy study.

The iteration count is reported per call so callers can charge it to the modules involved
(Funiak et al. 2008 Fig. 6). All quantities are made dimensionless by the module radius inside, so the
tolerances do not depend on units.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.sparse.linalg import splu

from decentral.ensemble.coarse import TwoLevelInverse, cluster_labels
from decentral.ensemble.ordering import ORDERINGS, choose_ordering, nested_dissection
from decentral.ensemble.problem import EnsembleProblem
from decentral.ensemble.rotation import angle_to_matrix, project_to_rotation, so3_exp, skew

__all__ = ["RefineConfig", "RefineResult", "refine", "LaplacianSolver"]


@dataclass(frozen=True)
class RefineConfig:
    """Stopping rules of :func:`refine`.

    Attributes
    ----------
    max_iter : int
        Maximum number of iterations: linear solves (accepted or rejected steps) for
        ``"alternating"`` and ``"lm"``, quasi-Newton steps for ``"lbfgs"``, conjugate-gradient
        steps for ``"pcg"``.
    gtol : float
        Stop when the largest gradient entry (in module radii) is below this (Funiak et al. 2008 §VI-B stops
        each level at a fixed gradient norm).
    ftol : float
        Stop when an accepted step lowers the cost by less than this fraction (for ``"lbfgs"`` and
        ``"alternating"``: when the last ``ftol_window`` accepted steps together do).
    ftol_window : int
        Number of accepted steps the ``ftol`` test looks back over (``"lbfgs"`` and
        ``"alternating"``). With one, a single small step in a plateau stops the run, so that the
        stopping point can move by a hundred iterations with rounding-level changes of the start;
        Algorithm 1's top refinement uses 20 steps and ``ftol`` 1e-10.
    damping : float
        Initial Levenberg-Marquardt damping (relative to the diagonal of J^T J), ``"lm"`` only.
    method : str
        ``"alternating"``, ``"lbfgs"``, ``"lm"`` or ``"pcg"``.
    history : int
        Anderson mixing depth (``"alternating"``; 0 disables acceleration), or the number of
        curvature pairs kept by ``"lbfgs"``.
    gnorm : str
        How ``gtol`` measures the gradient (in module radii): ``"max"``, its largest entry;
        ``"l2"``, its Euclidean norm, the "norm of the gradient" of Funiak et al. 2008 §VI-B. The gradient is
        the position gradient for ``"alternating"`` (its orientations are optimal for the centres
        after every sweep, so their gradient vanishes) and the whole gradient (positions and
        orientation increments) for ``"lm"`` and ``"pcg"``.
    ordering : str
        Fill-reducing ordering of the Laplacian factorization (``"alternating"`` and ``"lbfgs"``):
        ``"auto"`` (:func:`~decentral.ensemble.ordering.choose_ordering`: METIS nested dissection
        for 3D ensembles from 4,000 modules, else the caller's elimination order if it gives one,
        else SuperLU's minimum degree), ``"nd"``, ``"mmd"`` or ``"given"``. Changes the cost per
        iteration, not the iterates (up to rounding).
    coarse_size : int
        ``"lbfgs"`` only: modules per cluster of the two-level initial inverse Hessian
        (:mod:`decentral.ensemble.coarse`: the Laplacian plus rigid motions of METIS clusters of about
        this many modules), used on problems of at least twice this size; 0 keeps 4 L^-1 alone.
        Its coarse matrix is dense, m K square (m = 3 in 2D, 6 in 3D; K = n / coarse_size
        clusters), so keep K in the hundreds: 500 gives K = 40 at 20,000 modules, 200 at 100,000.
    """

    max_iter: int = 200
    gtol: float = 1e-6
    ftol: float = 1e-12
    ftol_window: int = 1
    damping: float = 1e-6
    method: str = "alternating"
    history: int = 6
    gnorm: str = "max"
    ordering: str = "auto"
    coarse_size: int = 0


@dataclass(frozen=True)
class RefineResult:
    """A refined estimate.

    Attributes
    ----------
    position : ndarray, shape (n, dim)
        Centres (metres).
    rotation : ndarray, shape (n, dim, dim)
    cost : float
        Negative log-likelihood 1/2 sum |r_e|^2 at the result (metres^2).
    gradient_norm : float
        Largest gradient entry at the result, in module radii.
    iterations : int
        Linear solves performed.
    status : str
        ``"converged"`` (gradient or relative decrease below tolerance), ``"max_iter"`` or
        ``"stalled"`` (damping grew without finding a decrease; the best point is returned).
    """

    position: np.ndarray
    rotation: np.ndarray
    cost: float
    gradient_norm: float
    iterations: int
    status: str


def _residual(i, j, z, c, R):
    rz = np.einsum("eab,eb->ea", R[i], z)
    return rz, rz - 0.5 * (c[j] - c[i])


def _jacobian(n, d, i, j, z, R, rz):
    E = i.size
    p = 1 if d == 2 else 3
    rows_e = np.arange(E) * d
    rows, cols, vals = [], [], []
    for a in range(d):
        rows += [rows_e + a, rows_e + a]
        cols += [i * d + a, j * d + a]
        vals += [np.full(E, 0.5), np.full(E, -0.5)]
    if d == 2:
        drz = np.stack([-rz[:, 1], rz[:, 0]], 1)  # d(R(theta) z)/d theta = J R z
        for a in range(2):
            rows.append(rows_e + a)
            cols.append(n * d + i)
            vals.append(drz[:, a])
    else:
        # d(R exp([w]x) z)/dw at w = 0 is -R [z]x
        Jr = -np.einsum("eab,ebc->eac", R[i], skew(z))
        for a in range(3):
            for b in range(3):
                rows.append(rows_e + a)
                cols.append(n * d + 3 * i + b)
                vals.append(Jr[:, a, b])
    J = sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                          shape=(E * d, n * (d + p)))
    return J


def _retract(d, c, R, step, n):
    dc = step[: n * d].reshape(n, d)
    dr = step[n * d:]
    if d == 2:
        Rn = R @ angle_to_matrix(dr)
    else:
        Rn = R @ so3_exp(dr.reshape(n, 3))
    return c + dc, Rn


class LaplacianSolver:
    """Least-squares centres for fixed orientations, with the Laplacian factorized once.

    For fixed orientations the negative log-likelihood is (1/8) sum_e |c_j - c_i - 2 R_i z_e|^2, whose
    normal matrix is the Laplacian of the directed observation multigraph. One node per connected
    component is held fixed (the problem is translation invariant), the rest solved by a sparse LU of
    the reduced Laplacian (SuperLU, symmetric mode, no pivoting) in a fill-reducing order: SuperLU's
    minimum degree or METIS nested dissection (:mod:`decentral.ensemble.ordering`).

    Parameters
    ----------
    n : int
    i, j : ndarray of int, shape (E,)
        Directed observations.
    adjacency : scipy.sparse matrix, shape (n, n), optional
        The contact graph (built from ``i``, ``j`` when not given).
    fixed : ndarray of bool, shape (n,), optional
        Modules whose centres are held at ``current`` in :meth:`solve` (Dirichlet nodes); a
        component with none of them still gets its first node held.
    ordering : str
        ``"mmd"`` (minimum degree), ``"nd"`` (METIS nested dissection) or ``"given"`` (``elimination``).
    elimination : ndarray of int, shape (n,), optional
        An elimination order of the modules (a permutation of 0..n-1), for ``ordering="given"``.
    """

    def __init__(self, n: int, i: np.ndarray, j: np.ndarray, adjacency: sparse.csr_matrix | None = None,
                 fixed: np.ndarray | None = None, ordering: str = "mmd", elimination: np.ndarray | None = None):
        from scipy.sparse.csgraph import connected_components

        if ordering not in ("nd", "mmd", "given"):
            raise ValueError(f"unknown ordering {ordering!r} (nd, mmd or given)")
        if ordering == "given" and (elimination is None or np.shape(elimination) != (n,)):
            raise ValueError(f"ordering 'given' needs an elimination order of shape ({n},)")
        self.n, self.i, self.j = n, i, j
        if adjacency is None:
            adjacency = sparse.csr_matrix((np.ones(i.size), (i, j)), shape=(n, n))
        _, labels = connected_components(adjacency, directed=False)
        free = np.ones(n, dtype=bool) if fixed is None else ~np.asarray(fixed, dtype=bool)
        # a component without a held module gets one (the problem is translation invariant)
        anchored = np.zeros(int(labels.max()) + 1 if n else 0, dtype=bool)
        anchored[labels[~free]] = True
        _, idx = np.unique(labels, return_index=True)
        free[idx[~anchored]] = False
        self.free = free
        index = np.cumsum(free) - 1
        deg = np.bincount(i, minlength=n) + np.bincount(j, minlength=n)
        self.index = index
        self.e_free_fixed = np.flatnonzero(free[i] & ~free[j])
        self.e_fixed_free = np.flatnonzero(~free[i] & free[j])
        self.lu, self.perm = None, None
        m = int(free.sum())
        if not m:
            return
        # reduced Laplacian of the directed observation multigraph, built straight from the edges:
        # each directed observation (a, b) adds -1 at (a, b) and at (b, a); CSC arrays are assembled
        # by one sort instead of scipy's generic COO path (this constructor runs once per refinement,
        # hundreds of times per localization)
        ff = free[i] & free[j]
        a, b = index[i[ff]], index[j[ff]]
        rows = np.concatenate([a, b, np.arange(m)])
        cols = np.concatenate([b, a, np.arange(m)])
        vals = np.concatenate([np.full(2 * a.size, -1.0), deg[free].astype(float)])
        key = cols * m + rows
        order = np.argsort(key, kind="stable")
        key = key[order]
        first = np.ones(key.size, dtype=bool)
        first[1:] = key[1:] != key[:-1]
        starts = np.flatnonzero(first)
        data = np.add.reduceat(vals[order], starts)
        indices = rows[order][starts].astype(np.int32)
        indptr = np.searchsorted(cols[order][starts], np.arange(m + 1)).astype(np.int32)
        Lr = sparse.csc_matrix((data, indices, indptr), shape=(m, m))
        if ordering == "nd" and m > 1:
            self.perm = nested_dissection(Lr)
        elif ordering == "given":
            order = np.asarray(elimination)
            self.perm = index[order[free[order]]]
        if self.perm is None:
            self.lu = splu(Lr, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                           options={"SymmetricMode": True})
        else:
            self.lu = splu(Lr[self.perm][:, self.perm].tocsc(), permc_spec="NATURAL", diag_pivot_thresh=0.0,
                           options={"SymmetricMode": True})

    def solve_reduced(self, rhs: np.ndarray) -> np.ndarray:
        """L_r^-1 rhs for right-hand sides (m, d) on the free modules (in ``free`` order); zeros when
        nothing is free."""
        if self.lu is None:
            return np.zeros_like(rhs)
        if self.perm is None:
            return self.lu.solve(np.ascontiguousarray(rhs))
        out = np.empty_like(rhs)
        out[self.perm] = self.lu.solve(np.ascontiguousarray(rhs[self.perm]))
        return out

    def solve(self, t: np.ndarray, current: np.ndarray) -> np.ndarray:
        """Centres (n, d) minimizing sum_e |c_j - c_i - t_e|^2, the fixed nodes kept at ``current``."""
        n, d = self.n, t.shape[1]
        i, j, free, index = self.i, self.j, self.free, self.index
        c = np.array(current, dtype=float, copy=True)
        if self.lu is None:
            return c
        m = int(free.sum())
        rhs = np.empty((m, d))
        e1, e2 = self.e_free_fixed, self.e_fixed_free
        for a in range(d):
            b = np.bincount(j, t[:, a], n) - np.bincount(i, t[:, a], n)
            # move the fixed neighbours' known centres to the right-hand side
            b += np.bincount(i[e1], c[j[e1], a], n) + np.bincount(j[e2], c[i[e2], a], n)
            rhs[:, a] = b[free]
        c[free] = self.solve_reduced(rhs)
        return c


def _row_matrix(columns: np.ndarray, values: np.ndarray, n_cols: int) -> sparse.csr_matrix:
    """CSR matrix (E, n_cols) whose row e holds ``values[e]`` at ``columns[e]`` (both (E, k), k per row)."""
    rows, k = columns.shape
    return sparse.csr_matrix((values.ravel(), columns.ravel(), np.arange(0, rows * k + 1, k)),
                             shape=(rows, n_cols))


class _Incidence:
    """The observation graph as sparse operators on centres (n, d) and per-observation arrays (E, d).

    ``half(c)`` = (c_j - c_i) / 2 per observation, B c with B the (E, n) incidence matrix scaled by
    1/2; ``gradient(r)`` = (sum_{e: i_e = k} r_e - sum_{e: j_e = k} r_e) / 2 per module, -B^T r: the
    position gradient of (1/2) sum_e |r_e|^2 with r_e = R_i z_e - (c_j - c_i) / 2. One sparse product
    each instead of one scatter per coordinate and end (3-5x faster on 5,000-20,000-module 3D ensembles).
    """

    def __init__(self, n: int, i: np.ndarray, j: np.ndarray):
        self.B = _row_matrix(np.stack([i, j], 1), np.tile([-0.5, 0.5], (i.size, 1)), n)
        self.BT = self.B.T.tocsr()

    def half(self, c: np.ndarray) -> np.ndarray:
        return self.B @ c

    def gradient(self, r: np.ndarray) -> np.ndarray:
        g = self.BT @ r
        np.negative(g, out=g)
        return g


class _Rotations:
    """Orientation model shared by 2D and 3D: observations as a sparse operator on stacked matrices.

    ``Z`` (E, d n) holds z_e at the columns (i_e, 0..d-1), so ``Z @ Rt`` with ``Rt[(i, b), a] =
    R_i[a, b]`` gives R_i z_e for every observation, and ``Z^T @ h`` gives the per-module sums
    M_i[a, b] = sum_e h_e[a] z_e[b] that the closed-form fit needs (Funiak et al. 2008 eq. (1) per module).
    """

    def __init__(self, i, z, n):
        d = z.shape[1]
        self.n, self.d = n, d
        self.Z = _row_matrix(d * i[:, None] + np.arange(d), z, d * n)
        self.ZT = self.Z.T.tocsr()

    def rotate(self, R: np.ndarray) -> np.ndarray:
        """R_i z_e for every observation (E, d) from matrices R (n, d, d)."""
        return self.Z @ np.ascontiguousarray(R.transpose(0, 2, 1)).reshape(-1, self.d)

    def moments(self, dvec: np.ndarray) -> np.ndarray:
        """M (n, d, d), M_i[a, b] = sum_{e: i_e = i} dvec_e[a] z_e[b]."""
        return (self.ZT @ dvec).reshape(self.n, self.d, self.d).transpose(0, 2, 1)


class _Rotations2D(_Rotations):
    """Orientation state as angles (cheaper than matrices for the planar sweeps)."""

    def from_matrices(self, R):
        return np.arctan2(R[:, 1, 0], R[:, 0, 0])

    def to_matrices(self, theta):
        return angle_to_matrix(theta)

    def apply(self, theta):
        return self.rotate(angle_to_matrix(theta))

    def fit(self, dvec):
        # Funiak et al. 2008 eq. (1) per module, closed form: theta = atan2(sum z x d, sum z . d)
        M = self.moments(dvec)
        return np.arctan2(M[:, 1, 0] - M[:, 0, 1], M[:, 0, 0] + M[:, 1, 1])


class _Rotations3D(_Rotations):
    """Orientation state as matrices (n, 3, 3)."""

    def __init__(self, i, z, n):
        super().__init__(i, z, n)
        self.lonely = np.bincount(i, minlength=n) == 0

    def from_matrices(self, R):
        return np.asarray(R, float)

    def to_matrices(self, R):
        return R

    def apply(self, R):
        return self.rotate(R)

    def fit(self, dvec):
        # per-module Kabsch fit of R z_ij onto (c_j - c_i)/2
        M = self.moments(dvec)
        M[self.lonely] = np.eye(3)
        return project_to_rotation(M)


class _DecreaseTest:
    """The relative-decrease stopping test of the block refiners: called with the cost after each
    accepted step, true when the last ``ftol_window`` steps together lowered it by less than ``ftol``
    (relative to the cost before them). A window of one is the plain per-step test; a longer window
    does not fire on one small step in a plateau, so where a run stops no longer hangs on rounding."""

    def __init__(self, config: "RefineConfig", start: float):
        self.ftol, self.window = config.ftol, max(int(config.ftol_window), 1)
        self.costs: list[float] = [start]

    def __call__(self, cost: float) -> bool:
        self.costs.append(cost)
        if len(self.costs) <= self.window:
            return False
        before = self.costs.pop(0)
        return 0 <= (before - cost) / max(before, 1e-300) < self.ftol


def _norm(g: np.ndarray, kind: str) -> float:
    """Largest entry (``"max"``) or Euclidean norm (``"l2"``) of a gradient array."""
    return float(np.sqrt(np.vdot(g, g))) if kind == "l2" else float(np.abs(g).max())


def _in_radii(problem: EnsembleProblem, position: np.ndarray, rotation: np.ndarray):
    """The refiners' working copies: observations (E, d) and centres (n, d) in module radii, orientations copied."""
    s = problem.radius
    return problem.z / s, np.asarray(position, float) / s, np.asarray(rotation, float).copy()


def _no_observations(x: np.ndarray, R: np.ndarray, s: float) -> RefineResult:
    """Nothing to refine: the start, back in metres."""
    return RefineResult(x * s, R, 0.0, 0.0, 0, "converged")


def _block_setup(problem: EnsembleProblem, z: np.ndarray, R0: np.ndarray, fixed: np.ndarray | None,
                 ordering: str = "auto", elimination: np.ndarray | None = None):
    """What the block refiners share: the Laplacian solver of the contact graph (held modules as
    Dirichlet nodes), the orientation model, the held indices, and the closed-form orientation fit
    ``fit(half) -> state`` (``half`` = (c_j - c_i) / 2 per observation, (E, dim), in radii) that keeps
    held modules at their orientations in ``R0``, and the incidence operators (:class:`_Incidence`)."""
    free = problem.n if fixed is None else problem.n - int(np.count_nonzero(fixed))
    lap = LaplacianSolver(problem.n, problem.i, problem.j, problem.adjacency(), fixed,
                          choose_ordering(ordering, problem.dim, free, elimination is not None), elimination)
    rots = (_Rotations2D if problem.dim == 2 else _Rotations3D)(problem.i, z, problem.n)
    held = None if fixed is None else np.flatnonzero(fixed)
    held_state = None if held is None else rots.from_matrices(R0)[held].copy()

    def fit(half):
        state = rots.fit(half)
        if held is not None:
            state[held] = held_state
        return state

    return lap, rots, held, fit, _Incidence(problem.n, problem.i, problem.j)


def _refine_alternating(problem: EnsembleProblem, position: np.ndarray, rotation: np.ndarray,
                        config: RefineConfig, fixed: np.ndarray | None = None,
                        elimination: np.ndarray | None = None) -> RefineResult:
    n, d, s = problem.n, problem.dim, problem.radius
    z, x, R0 = _in_radii(problem, position, rotation)
    if problem.num_observations == 0:
        return _no_observations(x, R0, s)
    lap, rots, held, fit, inc = _block_setup(problem, z, R0, fixed, config.ordering, elimination)

    def gradient(r):  # position gradient of the free modules (held ones do not move)
        g = inc.gradient(r)
        if held is not None:
            g[held] = 0.0
        return g

    def evaluate(half, state):  # half = (c_j - c_i) / 2 per observation
        rz = rots.apply(state)
        r = rz - half
        return state, rz, r, 0.5 * float(np.einsum("ea,ea->", r, r))

    def energy(c):  # best orientations for the centres c (local step) and the resulting cost
        half = inc.half(c)
        return evaluate(half, fit(half))

    # start from the given orientations if they are better than the fitted ones
    R, rz, r, E = energy(x)
    given = evaluate(inc.half(x), rots.from_matrices(rotation))
    if given[3] < E:
        R, rz, r, E = given
    levelled_off = _DecreaseTest(config, E)
    dF: list[np.ndarray] = []
    dG: list[np.ndarray] = []
    f_prev = g_prev = None
    it = 0
    status = "max_iter"
    gnorm = _norm(gradient(r), config.gnorm)
    while it < config.max_iter:
        if gnorm <= config.gtol or E <= 1e-30:
            status = "converged"
            break
        it += 1
        g = lap.solve(2.0 * rz, x)  # global step: best centres for the current orientations
        f = g - x
        if f_prev is not None and config.history > 0:
            dF.append((f - f_prev).ravel())
            dG.append((g - g_prev).ravel())
            if len(dF) > config.history:
                dF.pop(0)
                dG.pop(0)
        f_prev, g_prev = f, g
        x_new = g
        if dF:
            Fm = np.stack(dF, 1)
            # Anderson weights from the normal equations of the small (<= history) least-squares
            # problem, lightly regularized (faster than an SVD-based lstsq on a tall matrix)
            G = Fm.T @ Fm
            G.flat[:: G.shape[0] + 1] += 1e-12 * np.trace(G) + 1e-300
            try:
                gamma = np.linalg.solve(G, Fm.T @ f.ravel())
            except np.linalg.LinAlgError:
                gamma, *_ = np.linalg.lstsq(Fm, f.ravel(), rcond=None)
            x_new = g - (np.stack(dG, 1) @ gamma).reshape(n, d)
        R_new, rz_new, r_new, E_new = energy(x_new)
        if dF and not E_new <= E:
            # safeguard: the accelerated point is worse; take the plain (monotone) sweep. The
            # history is kept: clearing it on every rejection (38 of 100 sweeps on a 3D solid)
            # threw away the slow modes it had learned, and the plain sweeps crawl along them.
            x_new = g
            R_new, rz_new, r_new, E_new = energy(g)
        x, R, rz, r, E = x_new, R_new, rz_new, r_new, E_new
        gnorm = _norm(gradient(r), config.gnorm)
        if gnorm <= config.gtol or E <= 1e-30 or levelled_off(E):
            status = "converged"
            break
    return RefineResult(x * s, rots.to_matrices(R), E * s * s, gnorm, it, status)


def refine(problem: EnsembleProblem, position: np.ndarray, rotation: np.ndarray,
           config: RefineConfig = RefineConfig(), fixed: np.ndarray | None = None,
           elimination: np.ndarray | None = None) -> RefineResult:
    """Maximize the likelihood (Funiak et al. 2008 eq. 3) starting from ``position`` (n, d), ``rotation`` (n, d, d).

    Parameters
    ----------
    problem : EnsembleProblem
    position : ndarray, shape (n, dim)
        Initial centres (metres).
    rotation : ndarray, shape (n, dim, dim)
        Initial orientations.
    config : RefineConfig
    fixed : ndarray of bool, shape (n,), optional
        Modules held at their given pose (``"alternating"`` and ``"lbfgs"``): the likelihood is maximized over
        the other modules, with every observation still counted. Used to refine the seam of a merge
        inside a ring of already refined modules (:class:`~decentral.ensemble.HierarchyConfig`
        ``seam_hops``).
    elimination : ndarray of int, shape (n,), optional
        An elimination order of the modules for the Laplacian factorization (``"alternating"`` and
        ``"lbfgs"``; used as ``config.ordering`` says, see :class:`RefineConfig`), e.g. Algorithm 1's
        cuts as a nested dissection (:func:`~decentral.ensemble.ordering.hierarchy_order`).

    Returns
    -------
    RefineResult
        The best estimate found, never NaN; a numerical failure ends the iteration with status
        ``"stalled"`` at the best point so far. With ``fixed``, the gradient norm is over the free
        modules.
    """
    if config.gnorm not in ("max", "l2"):
        raise ValueError(f"unknown gradient norm {config.gnorm!r} (max or l2)")
    if config.ordering not in ORDERINGS:
        raise ValueError(f"unknown ordering {config.ordering!r} ({', '.join(ORDERINGS)})")
    if not config.coarse_size >= 0:
        raise ValueError(f"coarse_size must be >= 0, got {config.coarse_size!r}")
    if elimination is not None:
        elimination = np.asarray(elimination, dtype=np.int64)
        if elimination.shape != (problem.n,) or not np.array_equal(np.sort(elimination), np.arange(problem.n)):
            raise ValueError(f"elimination must be a permutation of 0..{problem.n - 1}")
    if config.ordering == "given" and elimination is None:
        raise ValueError("ordering 'given' needs an elimination order")
    if fixed is not None:
        fixed = np.asarray(fixed, dtype=bool)
        if fixed.shape != (problem.n,):
            raise ValueError(f"fixed has shape {fixed.shape}, expected ({problem.n},)")
        if config.method == "alternating":
            return _refine_alternating(problem, position, rotation, config, fixed, elimination)
        if config.method == "lbfgs":
            return _refine_lbfgs(problem, position, rotation, config, fixed, elimination)
        raise ValueError(f"held modules need the alternating or lbfgs refiner, not {config.method!r}")
    if config.method == "lm":
        return _refine_lm(problem, position, rotation, config)
    if config.method == "alternating":
        return _refine_alternating(problem, position, rotation, config, None, elimination)
    if config.method == "pcg":
        return _refine_pcg(problem, position, rotation, config)
    if config.method == "lbfgs":
        return _refine_lbfgs(problem, position, rotation, config, None, elimination)
    raise ValueError(f"unknown refinement method {config.method!r}")


def _refine_lbfgs(problem: EnsembleProblem, position: np.ndarray, rotation: np.ndarray,
                  config: RefineConfig, fixed: np.ndarray | None = None,
                  elimination: np.ndarray | None = None) -> RefineResult:
    """L-BFGS on the centres with the orientations fitted in closed form (variable projection).

    F(c) = min_R cost(c, R); by the envelope theorem its gradient is the position gradient at the
    fitted orientations. The initial inverse Hessian is 4 L^-1, the exact inverse of the position
    block (cost = (1/8) |B c - 2 R z|^2 for fixed R, B the incidence matrix, L = B^T B), applied
    with the factorized Laplacian; one module per component is held (translation gauge). With
    ``config.coarse_size`` > 0 (and at least twice that many modules) it is the two-level operator
    of :class:`~decentral.ensemble.coarse.TwoLevelInverse`, built once at the start.
    """
    s = problem.radius
    z, x, R0 = _in_radii(problem, position, rotation)
    if problem.num_observations == 0:
        return _no_observations(x, R0, s)
    lap, rots, _, fit, inc = _block_setup(problem, z, R0, fixed, config.ordering, elimination)
    free = lap.free

    def reduced(c):  # F(c), its gradient (n, d) and the fitted orientations (held ones kept)
        half = inc.half(c)
        state = fit(half)
        r = rots.apply(state) - half
        g = inc.gradient(r)  # envelope theorem: the orientations are optimal
        g[~free] = 0.0
        # Funiak et al. 2008 eq. (3): negative log-likelihood 1/2 sum_e |R_i z_e - (c_j - c_i)/2|^2
        return 0.5 * float(np.einsum("ea,ea->", r, r)), g, state

    def fine(v):  # 4 L^-1 v on the free modules
        out = np.zeros_like(v)
        out[free] = 4.0 * lap.solve_reduced(v[free])
        return out

    E, g, state = reduced(x)  # the closed-form fit is never worse than the given orientations
    h0 = fine
    if config.coarse_size > 0 and problem.n >= 2 * config.coarse_size:
        turning = np.ones(problem.n, dtype=bool) if fixed is None else ~fixed
        h0 = TwoLevelInverse(problem.i, problem.j, inc.B, x, rots.apply(state),
                             cluster_labels(problem.adjacency(), config.coarse_size), free, turning, fine)
    levelled_off = _DecreaseTest(config, E)
    S: list[np.ndarray] = []
    Y: list[np.ndarray] = []
    rho: list[float] = []
    it = 0
    status = "max_iter"
    gnorm = _norm(g, config.gnorm)
    while it < config.max_iter:
        if gnorm <= config.gtol or E <= 1e-30:
            status = "converged"
            break
        it += 1
        # two-loop recursion: p = -H g
        q = g.copy()
        alphas = []
        for sk, yk, rk in zip(reversed(S), reversed(Y), reversed(rho)):
            a = rk * float(np.vdot(sk, q))
            alphas.append(a)
            q -= a * yk
        p = h0(q)
        for sk, yk, rk, a in zip(S, Y, rho, reversed(alphas)):
            p += (a - rk * float(np.vdot(yk, p))) * sk
        p = -p
        slope = float(np.vdot(g, p))
        if not slope < 0:  # the memory lost positive definiteness numerically: restart
            S, Y, rho = [], [], []
            p = -h0(g)
            slope = float(np.vdot(g, p))
            if not slope < 0:
                status = "stalled"
                break
        t = 1.0
        for _ in range(30):
            x_new = x + t * p
            E_new, g_new, state_new = reduced(x_new)
            if E_new <= E + 1e-4 * t * slope:
                break
            t *= 0.5
        else:
            status = "stalled"
            break
        sk, yk = x_new - x, g_new - g
        sy = float(np.vdot(sk, yk))
        if sy > 1e-12 * float(np.vdot(yk, yk)):  # keep only pairs with positive curvature
            S.append(sk)
            Y.append(yk)
            rho.append(1.0 / sy)
            if len(S) > max(config.history, 1):
                S.pop(0)
                Y.pop(0)
                rho.pop(0)
        x, E, g, state = x_new, E_new, g_new, state_new
        gnorm = _norm(g, config.gnorm)
        if gnorm <= config.gtol or E <= 1e-30 or levelled_off(E):
            status = "converged"
            break
    return RefineResult(x * s, rots.to_matrices(state), E * s * s, gnorm, it, status)


def _refine_lm(problem: EnsembleProblem, position: np.ndarray, rotation: np.ndarray,
               config: RefineConfig) -> RefineResult:
    n, d, s = problem.n, problem.dim, problem.radius
    i, j = problem.i, problem.j
    z, c, R = _in_radii(problem, position, rotation)
    if i.size == 0:
        return _no_observations(c, R, s)
    rz, r = _residual(i, j, z, c, R)
    cost = 0.5 * float(np.einsum("ea,ea->", r, r))
    lam = config.damping
    it = 0
    status = "max_iter"
    gnorm = np.inf
    J = _jacobian(n, d, i, j, z, R, rz)
    g = J.T @ r.ravel()
    gnorm = _norm(g, config.gnorm)
    while it < config.max_iter:
        if gnorm <= config.gtol or cost <= 1e-30:
            status = "converged"
            break
        H = (J.T @ J).tocsc()
        diag = H.diagonal()
        A = H + sparse.diags(lam * diag + 1e-12)
        it += 1
        try:
            step = splu(A.tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                        options={"SymmetricMode": True}).solve(-g)
        except RuntimeError:
            status = "stalled"
            break
        if not np.all(np.isfinite(step)):
            status = "stalled"
            break
        c_new, R_new = _retract(d, c, R, step, n)
        rz_new, r_new = _residual(i, j, z, c_new, R_new)
        cost_new = 0.5 * float(np.einsum("ea,ea->", r_new, r_new))
        if cost_new < cost:
            decrease = (cost - cost_new) / max(cost, 1e-300)
            c, R, rz, r, cost = c_new, R_new, rz_new, r_new, cost_new
            lam = max(lam / 10.0, 1e-12)
            J = _jacobian(n, d, i, j, z, R, rz)
            g = J.T @ r.ravel()
            gnorm = _norm(g, config.gnorm)
            if decrease < config.ftol:
                status = "converged"
                break
        else:
            lam *= 10.0
            if lam > 1e8:
                status = "stalled"
                break
    else:
        if gnorm <= config.gtol:
            status = "converged"
    return RefineResult(c * s, R, cost * s * s, gnorm, it, status)


def _refine_pcg(problem: EnsembleProblem, position: np.ndarray, rotation: np.ndarray,
                config: RefineConfig) -> RefineResult:
    """Preconditioned nonlinear conjugate gradient on eq. 2 (the refiner of Funiak et al. 2008 §VI-B/E).

    Every iteration costs a fixed number of passes over the observations (gradient, one
    Jacobian-vector product, one or a few cost evaluations): no factorization, so information
    travels about one contact per iteration, which is what makes errors piled up far from where
    they are corrected slow to undo (Funiak et al. 2008 Fig. 3c). Positions move freely; orientations move
    by a right increment ``R exp([w]x)`` (an angle in 2D). The preconditioner is the block
    diagonal of the Gauss-Newton matrix (deg/4 per centre, sum |z|^2 per planar angle, sum
    (|z|^2 I - z z^T) per 3D increment); directions follow Polak-Ribiere+, the step is the
    Gauss-Newton minimizer along the direction, halved until the cost decreases (Armijo).
    """
    n, d, s = problem.n, problem.dim, problem.radius
    i, j = problem.i, problem.j
    z, x, R = _in_radii(problem, position, rotation)
    if i.size == 0:
        return _no_observations(x, R, s)
    p = 1 if d == 2 else 3
    deg = np.bincount(i, minlength=n) + np.bincount(j, minlength=n)
    px = 1.0 / np.maximum(deg / 4.0, 1e-12)
    zz = np.einsum("ea,ea->e", z, z)
    if d == 2:
        pr = 1.0 / np.maximum(np.bincount(i, zz, n), 1e-12)
    else:
        B = np.zeros((n, 3, 3))
        for a in range(3):
            for b in range(3):
                B[:, a, b] = np.bincount(i, (zz if a == b else 0.0) - z[:, a] * z[:, b], n)
        B += (1e-6 * np.trace(B, axis1=1, axis2=2)[:, None, None] + 1e-12) * np.eye(3)
        pr = np.linalg.inv(B)

    def rot_apply(Rm):
        return np.einsum("eab,eb->ea", Rm[i], z)

    def cost_grad(xc, Rm):
        rz = rot_apply(Rm)
        r = rz - 0.5 * (xc[j] - xc[i])
        gx = np.empty((n, d))
        for a in range(d):
            gx[:, a] = 0.5 * (np.bincount(i, r[:, a], n) - np.bincount(j, r[:, a], n))
        if d == 2:
            # d(R(theta) z)/d theta = J R z with J the 90-degree rotation
            gr = np.bincount(i, rz[:, 0] * r[:, 1] - rz[:, 1] * r[:, 0], n)[:, None]
        else:
            # d(R exp([w]x) z)/dw = -R [z]x, so the gradient is sum_e z x (R^T r_e)
            rl = np.einsum("eba,eb->ea", Rm[i], r)
            cz = np.cross(z, rl)
            gr = np.stack([np.bincount(i, cz[:, a], n) for a in range(3)], 1)
        return 0.5 * float(np.einsum("ea,ea->", r, r)), gx, gr, rz

    def precondition(gx, gr):
        hx = gx * px[:, None]
        hr = gr * pr[:, None] if d == 2 else np.einsum("nab,nb->na", pr, gr)
        return hx, hr

    def norm(gx, gr):
        if config.gnorm == "l2":
            return float(np.sqrt(np.einsum("na,na->", gx, gx) + np.einsum("na,na->", gr, gr)))
        return float(np.abs(gx).max())

    def retract(xc, Rm, dx, dr, alpha):
        if d == 2:
            return xc + alpha * dx, Rm @ angle_to_matrix(alpha * dr[:, 0])
        return xc + alpha * dx, Rm @ so3_exp(alpha * dr)

    E, gx, gr, rz = cost_grad(x, R)
    gnorm = norm(gx, gr)
    hx, hr = precondition(gx, gr)
    dx, dr = -hx, -hr
    gh = float(np.einsum("na,na->", gx, hx) + np.einsum("na,na->", gr, hr))
    it = 0
    status = "max_iter"
    while it < config.max_iter:
        if gnorm <= config.gtol or E <= 1e-30:
            status = "converged"
            break
        it += 1
        slope = float(np.einsum("na,na->", gx, dx) + np.einsum("na,na->", gr, dr))
        if not slope < 0:  # not a descent direction: restart from the preconditioned gradient
            dx, dr = -hx, -hr
            slope = -gh
        # Gauss-Newton step along the direction: alpha = -g.d / |J d|^2
        if d == 2:
            jr = dr[i, 0][:, None] * np.stack([-rz[:, 1], rz[:, 0]], 1)
        else:
            jr = np.einsum("eab,eb->ea", R[i], np.cross(dr[i], z))
        jd = jr + 0.5 * (dx[i] - dx[j])
        curv = float(np.einsum("ea,ea->", jd, jd))
        alpha = -slope / curv if curv > 0 else 1.0
        accepted = False
        for _ in range(30):
            xn, Rn = retract(x, R, dx, dr, alpha)
            En, gxn, grn, rzn = cost_grad(xn, Rn)
            if En <= E + 1e-4 * alpha * slope:
                accepted = True
                break
            alpha *= 0.5
        if not accepted:
            status = "stalled"
            break
        decrease = (E - En) / max(E, 1e-300)
        hxn, hrn = precondition(gxn, grn)
        ghn = float(np.einsum("na,na->", gxn, hxn) + np.einsum("na,na->", grn, hrn))
        # Polak-Ribiere+: beta = max(0, g_new . (h_new - h_old) / g_old . h_old)
        beta = max(0.0, (ghn - float(np.einsum("na,na->", gxn, hx) + np.einsum("na,na->", grn, hr))) / max(gh, 1e-300))
        dx, dr = -hxn + beta * dx, -hrn + beta * dr
        x, R, E, gx, gr, rz, hx, hr, gh = xn, Rn, En, gxn, grn, rzn, hxn, hrn, ghn
        gnorm = norm(gx, gr)
        if gnorm <= config.gtol or E <= 1e-30 or 0 <= decrease < config.ftol:
            status = "converged"
            break
    return RefineResult(x * s, R, E * s * s, norm(gx, gr), it, status)
