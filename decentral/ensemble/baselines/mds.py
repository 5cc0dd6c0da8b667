"""Classical multidimensional scaling of hop counts (Funiak et al. 2008 §VI-E (i); Shang et al., MDS-MAP [1]_).

Distances between all pairs of modules are approximated by the hop count times the model's contact
spacing (two radii); classical MDS embeds them in ``dim`` dimensions. All-pairs hop counts are
O(n^2) in time and memory by nature, so a size guard refuses large inputs.

References
----------
.. [1] Y. Shang, W. Ruml, Y. Zhang, M. Fromherz, "Localization from mere connectivity", MobiHoc 2003.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import eigh
from scipy.sparse.csgraph import shortest_path

from decentral.ensemble.baselines.common import FINAL_REFINE, run_per_component
from decentral.ensemble.hierarchical import LocalizationResult
from decentral.ensemble.problem import EnsembleProblem
from decentral.ensemble.refine import RefineConfig
from decentral.errors import SolverError

__all__ = ["MDS_MAX_NODES", "classical_mds", "mds_positions"]

#: largest component classical MDS accepts (its all-pairs matrix takes 8 n^2 bytes)
MDS_MAX_NODES = 8000


def mds_positions(problem: EnsembleProblem) -> np.ndarray:
    """Classical-MDS centres (n, dim) of a connected problem from hop counts x 2 radii."""
    n, d = problem.n, problem.dim
    if n > MDS_MAX_NODES:
        raise SolverError(f"classical MDS needs all-pairs hop counts: {n} modules exceed its size guard "
                          f"of {MDS_MAX_NODES}")
    if n <= d:
        return np.zeros((n, d))
    D = shortest_path(problem.adjacency(), unweighted=True, directed=False) * (2.0 * problem.radius)
    D2 = D * D
    # double centring: B = -1/2 J D^2 J
    B = -0.5 * (D2 - D2.mean(0)[None, :] - D2.mean(1)[:, None] + D2.mean())
    vals, vecs = eigh(B, subset_by_index=[n - d, n - 1])
    return vecs[:, ::-1] * np.sqrt(np.maximum(vals[::-1], 0.0))


def classical_mds(problem: EnsembleProblem, refine_config: RefineConfig | None = FINAL_REFINE) -> LocalizationResult:
    """Localize by classical MDS of hop counts, then fit orientations and refine (None: no refinement).

    Raises :class:`SolverError` when a component exceeds :data:`MDS_MAX_NODES` modules.
    """
    return run_per_component(problem, lambda sub: (mds_positions(sub), None, np.zeros(sub.n)), refine_config,
                             {"method": "mds"})
