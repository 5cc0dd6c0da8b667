"""The incremental breadth-first method of seed 003 §III-B (the motivation for Algorithm 1).

Starting from one module, the set A of localized modules grows one breadth-first layer at a time:
the new modules are placed from their localized neighbours and the maximum likelihood of all
observations among A is refined from there. Errors made early in weak regions are carried along
and only resolved, slowly, when a loop closes (seed 003 Fig. 3). Each step refines all of A, so the
work grows as n times the number of layers; it is a baseline for studies, not for large ensembles.
"""

from __future__ import annotations

import numpy as np

from decentral.ensemble.baselines.common import FINAL_REFINE, run_per_component
from decentral.ensemble.hierarchical import LocalizationResult
from decentral.ensemble.placement import LayerPlacer, bfs_layers
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
    n, d = problem.n, problem.dim
    A = problem.adjacency()
    if root is None:
        root = int(np.argmax(np.diff(A.indptr))) if n else 0
    pos = np.zeros((n, d))
    rot = np.tile(np.eye(d), (n, 1, 1))
    placed = np.zeros(n, dtype=bool)
    iters = np.zeros(n)
    if n == 0:
        return pos, rot, iters
    placed[root] = True
    placer = LayerPlacer(problem)
    for layer in bfs_layers(A, root)[1:]:
        placer.place(pos, rot, placed, layer)
        nodes = np.flatnonzero(placed)
        sub = problem.subproblem(nodes)
        res = refine(sub, pos[nodes], rot[nodes], step_refine)
        pos[nodes], rot[nodes] = res.position, res.rotation
        iters[nodes] += res.iterations
    return pos, rot, iters


def incremental_localize(problem: EnsembleProblem, refine_config: RefineConfig | None = FINAL_REFINE,
                         step_refine: RefineConfig = STEP_REFINE) -> LocalizationResult:
    """Localize by breadth-first incremental MLE from a module of highest degree, then refine."""
    return run_per_component(problem, lambda sub: incremental_initial(sub, step_refine), refine_config,
                             {"method": "incremental"})
