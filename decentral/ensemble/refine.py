"""Refinement of an ensemble estimate to the maximum likelihood (Funiak et al. 2008 eq. 3, Algorithm 1 line 11).

:func:`refine` checks its arguments and dispatches to one of four methods, each in its own module of
:mod:`decentral.ensemble.refiners` (``"alternating"``, the default; ``"lbfgs"``, the default of
Algorithm 1's hierarchy; ``"lm"``; ``"pcg"``, the refiner of the paper); docs/ensemble_refinement.md says
what each does and when it is the right one.
"""

from __future__ import annotations

import numpy as np

from decentral.ensemble.laplacian import LaplacianSolver
from decentral.ensemble.ordering import ORDERINGS
from decentral.ensemble.problem import EnsembleProblem
from decentral.ensemble.refiners import RefineConfig, RefineResult, refine_alternating, refine_lbfgs, refine_lm, refine_pcg

__all__ = ["RefineConfig", "RefineResult", "refine", "LaplacianSolver"]


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
            return refine_alternating(problem, position, rotation, config, fixed, elimination)
        if config.method == "lbfgs":
            return refine_lbfgs(problem, position, rotation, config, fixed, elimination)
        raise ValueError(f"held modules need the alternating or lbfgs refiner, not {config.method!r}")
    if config.method == "lm":
        return refine_lm(problem, position, rotation, config)
    if config.method == "alternating":
        return refine_alternating(problem, position, rotation, config, None, elimination)
    if config.method == "pcg":
        return refine_pcg(problem, position, rotation, config)
    if config.method == "lbfgs":
        return refine_lbfgs(problem, position, rotation, config, None, elimination)
    raise ValueError(f"unknown refinement method {config.method!r}")
