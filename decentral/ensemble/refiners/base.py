"""What the refinement methods share: their config and result, the stopping test and the block methods' set-up."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from decentral.ensemble.laplacian import LaplacianSolver
from decentral.ensemble.ordering import choose_ordering
from decentral.ensemble.problem import EnsembleProblem
from decentral.ensemble.rotation import Rotations2D, Rotations3D
from decentral.ensemble.sparse_ops import Incidence

__all__ = [
    "DecreaseTest",
    "RefineConfig",
    "RefineResult",
    "block_setup",
    "gradient_norm",
    "in_radii",
    "no_observations",
]


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


class DecreaseTest:
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


def gradient_norm(g: np.ndarray, kind: str) -> float:
    """Largest entry (``"max"``) or Euclidean norm (``"l2"``) of a gradient array."""
    return float(np.sqrt(np.vdot(g, g))) if kind == "l2" else float(np.abs(g).max())


def in_radii(problem: EnsembleProblem, position: np.ndarray, rotation: np.ndarray):
    """The refiners' working copies: observations (E, d) and centres (n, d) in module radii, orientations copied."""
    s = problem.radius
    return problem.z / s, np.asarray(position, float) / s, np.asarray(rotation, float).copy()


def no_observations(x: np.ndarray, R: np.ndarray, s: float) -> RefineResult:
    """Nothing to refine: the start, back in metres."""
    return RefineResult(x * s, R, 0.0, 0.0, 0, "converged")


def block_setup(problem: EnsembleProblem, z: np.ndarray, R0: np.ndarray, fixed: np.ndarray | None,
                 ordering: str = "auto", elimination: np.ndarray | None = None):
    """What the block refiners share: the Laplacian solver of the contact graph (held modules as
    Dirichlet nodes), the orientation model, the held indices, and the closed-form orientation fit
    ``fit(half) -> state`` (``half`` = (c_j - c_i) / 2 per observation, (E, dim), in radii) that keeps
    held modules at their orientations in ``R0``, and the incidence operators (:class:`Incidence`)."""
    free = problem.n if fixed is None else problem.n - int(np.count_nonzero(fixed))
    lap = LaplacianSolver(problem.n, problem.i, problem.j, problem.adjacency(), fixed,
                          choose_ordering(ordering, problem.dim, free, elimination is not None), elimination)
    rots = (Rotations2D if problem.dim == 2 else Rotations3D)(problem.i, z, problem.n)
    held = None if fixed is None else np.flatnonzero(fixed)
    held_state = None if held is None else rots.from_matrices(R0)[held].copy()

    def fit(half):
        state = rots.fit(half)
        if held is not None:
            state[held] = held_state
        return state

    return lap, rots, held, fit, Incidence(problem.n, problem.i, problem.j)
