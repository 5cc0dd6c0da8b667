"""The incremental breadth-first method of Funiak et al. 2008 §III-B (the motivation for Algorithm 1).

Starting from one module, the set A of localized modules grows one breadth-first layer at a time:
the new modules are placed from their localized neighbours and the maximum likelihood of all
observations among A is refined from there. Errors made early in weak regions are carried along
and only resolved, slowly, when a loop closes (Funiak et al. 2008 Fig. 3). Each step refines all of A, so the
work grows as n times the number of layers; it is a baseline for studies, not for large ensembles.
"""

from __future__ import annotations

import numpy as np

from decentral.ensemble.baselines.common import FINAL_REFINE, run_per_component
from decentral.ensemble.hierarchical import LocalizationResult
from decentral.ensemble.breadth_first import place_breadth_first
from decentral.ensemble.problem import EnsembleProblem
from decentral.ensemble.refine import RefineConfig, refine

__all__ = ["STEP_REFINE", "incremental_localize", "incremental_initial"]

#: refinement after each added layer
STEP_REFINE = RefineConfig(max_iter=20, gtol=1e-4)


def incremental_initial(problem: EnsembleProblem, step_refine: RefineConfig = STEP_REFINE,
                        root: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Breadth-first incremental MLE of a connected problem.

    Returns centres (n, d), orientations (n, d, d) and the refinement iterations charged to each
    module (n,).
    """
    iters = np.zeros(problem.n)

    def refine_placed(pos, rot, placed):
        nodes = np.flatnonzero(placed)
        res = refine(problem.subproblem(nodes), pos[nodes], rot[nodes], step_refine)
        pos[nodes], rot[nodes] = res.position, res.rotation
        iters[nodes] += res.iterations

    pos, rot, _ = place_breadth_first(problem, root, after_layer=refine_placed)
    return pos, rot, iters


def incremental_localize(problem: EnsembleProblem, refine_config: RefineConfig | None = FINAL_REFINE,
                         step_refine: RefineConfig = STEP_REFINE) -> LocalizationResult:
    """Localize by breadth-first incremental MLE from a module of highest degree, then refine."""
    return run_per_component(problem, lambda sub: incremental_initial(sub, step_refine), refine_config,
                             {"method": "incremental"})
