"""What every baseline shares: per-component solving and the final likelihood refinement."""

from __future__ import annotations

from typing import Callable

import numpy as np

from decentral.ensemble.hierarchical import LocalizationResult, localize_components
from decentral.ensemble.model import fit_orientations, residuals_from_matrices
from decentral.ensemble.problem import EnsembleProblem
from decentral.ensemble.refine import RefineConfig, refine

__all__ = ["FINAL_REFINE", "run_per_component"]

#: refinement applied to every baseline's initial solution (Funiak et al. 2008 §VI-E: 300 iterations)
FINAL_REFINE = RefineConfig(max_iter=300, gtol=1e-6)


def run_per_component(problem: EnsembleProblem,
                      initial: Callable[[EnsembleProblem], tuple[np.ndarray, np.ndarray | None, np.ndarray]],
                      refine_config: RefineConfig | None, info: dict) -> LocalizationResult:
    """Solve each connected component with ``initial(sub) -> (position, rotation or None, iterations (n,))``,
    fit orientations where none are given, refine with ``refine_config`` (None: no refinement) and
    lay the components side by side."""
    iters = np.zeros(problem.n)
    statuses: list[str] = []

    def solve(sub, nodes):
        pos, rot, it = initial(sub)
        if rot is None:
            rot = fit_orientations(sub, pos)
        iters[nodes] += it
        if refine_config is not None and sub.num_observations:
            res = refine(sub, pos, rot, refine_config)
            iters[nodes] += res.iterations
            if res.status == "stalled":
                statuses.append(res.status)
            pos, rot = res.position, res.rotation
        return pos, rot, 0.0

    est, _, _ = localize_components(problem, solve)
    r = residuals_from_matrices(problem, est.position, est.rotation)
    cost = 0.5 * float(np.einsum("ea,ea->", r, r))
    return LocalizationResult(est, cost, iters, "ok" if not statuses else "refinement stalled", (), info)
