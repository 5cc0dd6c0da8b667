"""Fill-reducing orderings for the factorized contact-graph Laplacians of the ensemble refiners.

Every block refiner factorizes the reduced Laplacian of the contact graph once per call and then
solves with it once per iteration, so the fill of the factor sets the cost of each iteration. On
the 3D ``triple3d`` hcp ensembles, SuperLU's own minimum-degree ordering fills in like
n^1.65 (0.83 M nonzeros in L + U at 5,000 modules, 8.2 M at 20,000); METIS nested dissection
(multilevel vertex separators, George's ordering for mesh-like graphs) fills in 0.69 M and 5.3 M,
factorizes 3x faster at 20,000 and solves 30 % faster. Below ``ND_MIN_SIZE`` free modules
computing the dissection costs more than it saves, and minimum degree is used.
"""

from __future__ import annotations

import numpy as np
from scipy import sparse

__all__ = ["ND_MIN_SIZE", "nested_dissection"]

#: free modules from which the Laplacian solver orders by nested dissection (measured break-even:
#: see docs/ensemble.md, "Measured: scalability")
ND_MIN_SIZE = 4000

#: METIS's random seed, fixed so that the ordering (and so every floating-point result) is reproducible
_METIS_SEED = 0


def nested_dissection(matrix: sparse.spmatrix) -> np.ndarray:
    """METIS nested-dissection ordering of a structurally symmetric sparse matrix.

    Parameters
    ----------
    matrix : scipy.sparse matrix, shape (m, m)
        Structurally symmetric (a reduced graph Laplacian); its diagonal is ignored.

    Returns
    -------
    perm : ndarray of int, shape (m,)
        The elimination order: ``matrix[perm][:, perm]`` is the matrix to factorize in natural order.
    """
    import pymetis

    a = sparse.csr_matrix(matrix)
    m = a.shape[0]
    rows = np.repeat(np.arange(m), np.diff(a.indptr))
    off = a.indices != rows
    xadj = np.concatenate([[0], np.cumsum(np.bincount(rows[off], minlength=m))])
    options = pymetis.Options(seed=_METIS_SEED)
    graph = pymetis.CSRAdjacency(adj_starts=xadj, adjacent=a.indices[off])
    perm, _ = pymetis.nested_dissection(graph, options=options)
    return np.asarray(perm, dtype=np.intp)
