"""Fill-reducing orderings for the factorized contact-graph Laplacians of the ensemble refiners.

Every block refiner factorizes the reduced Laplacian of the contact graph once per call and then
solves with it once per iteration, so the fill of the factor sets the cost of each iteration. On
the 3D ``triple3d`` hcp ensembles, SuperLU's own minimum-degree ordering fills in like n^1.65
(0.83 M nonzeros in L + U at 5,000 modules, 8.2 M at 20,000); METIS nested dissection (multilevel
vertex separators, George's ordering for mesh-like graphs) fills in 0.66 M and 5.3 M, and the
factorization plus a solve of three right-hand sides take 0.43 s and 15.6 ms at 20,000 modules
instead of 0.73 s and 23 ms (1.3 instead of 1.9 ms per solve at 5,000). Planar contact graphs have
small separators that minimum degree already finds: on the 2D ``triple`` the dissection saves no
fill (0.97 M against 1.03 M at 25,000 modules) and solves slower up to 25,000 modules (4.2 against
2.8 ms), and below about 4,000 free modules it costs more than it saves in 3D too. So ``"auto"``
orders 3D Laplacians of at least ``ND_MIN_SIZE`` modules by nested dissection, the others by the
caller's elimination order when it gives one (below), else by minimum degree.

Algorithm 1 itself is a nested dissection: each normalized cut separates its set into parts joined by
few observations, so the hierarchy of cuts gives an elimination order for free
(:func:`hierarchy_order`: the parts first, recursively, then the modules at the cut). On the 2D
``triple`` at 100,000 modules it fills more than minimum degree (7.2 M against 5.4 M) but needs no
ordering step, so the factorization takes 0.28 s instead of 0.66 s and a solve 20 instead of 26 ms;
in 3D METIS's separators are smaller (a solve of 15 against 23 ms at 20,000 modules), so ``"auto"``
uses the hierarchy's order only where it does not use METIS.
"""

from __future__ import annotations

import numpy as np
from scipy import sparse

__all__ = ["ND_MIN_SIZE", "ORDERINGS", "choose_ordering", "hierarchy_order", "metis_graph", "metis_options",
           "nested_dissection"]

#: accepted names: ``"auto"`` (the rule above), ``"nd"`` (METIS nested dissection), ``"mmd"`` (minimum
#: degree), ``"given"`` (the caller's elimination order)
ORDERINGS = ("auto", "nd", "mmd", "given")

#: modules from which a 3D Laplacian is ordered by nested dissection (measured break-even between
#: 3,000 and 5,000 free modules on triple3d)
ND_MIN_SIZE = 4000

#: METIS's random seed, fixed so that the ordering (and so every floating-point result) is reproducible
_METIS_SEED = 0


def choose_ordering(requested: str, dim: int, size: int, given: bool = False) -> str:
    """The ordering for a Laplacian of ``size`` modules of a ``dim``-D ensemble: ``"nd"`` (METIS),
    ``"given"`` (the caller's elimination order, when ``given``) or ``"mmd"``.

    Raises
    ------
    ValueError
        If ``requested`` is not one of :data:`ORDERINGS`.
    """
    if requested not in ORDERINGS:
        raise ValueError(f"unknown ordering {requested!r} ({', '.join(ORDERINGS)})")
    if requested != "auto":
        return requested
    if dim == 3 and size >= ND_MIN_SIZE:
        return "nd"
    return "given" if given else "mmd"


def hierarchy_order(i: np.ndarray, j: np.ndarray, part: np.ndarray, part_orders: list[np.ndarray]) -> np.ndarray:
    """Elimination order of a set cut into parts: the parts' own orders, then the cut's separator.

    Parameters
    ----------
    i, j : ndarray of int, shape (E,)
        Observations of the set (local ids).
    part : ndarray of int, shape (n,)
        Part of each module (0..P-1).
    part_orders : list of ndarray of int
        For each part p, an elimination order of its modules as local ids of the set (a permutation of
        ``np.flatnonzero(part == p)``).

    Returns
    -------
    order : ndarray of int, shape (n,)
        Every module once: the parts' orders concatenated with the separator moved to the end. The
        separator is, for each observation crossing the cut, its end in the later part, so removing it
        disconnects the parts (George's nested dissection, with Algorithm 1's cuts as separators).
    """
    full = np.concatenate(part_orders)
    crossing = part[i] != part[j]
    a, b = i[crossing], j[crossing]
    separator = np.zeros(part.size, dtype=bool)
    separator[np.where(part[a] > part[b], a, b)] = True
    last = separator[full]
    return np.concatenate([full[~last], full[last]])


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

    perm, _ = pymetis.nested_dissection(metis_graph(matrix), options=metis_options())
    return np.asarray(perm, dtype=np.intp)


def metis_graph(matrix: sparse.spmatrix):
    """The graph of a sparse matrix (n, n) as METIS takes it: the symmetrized pattern without the
    diagonal, a ``pymetis.CSRAdjacency``."""
    import pymetis

    a = sparse.csr_matrix(matrix, dtype=float)
    a = ((a + a.T) != 0).astype(np.int8).tocsr()
    a.setdiag(0)
    a.eliminate_zeros()
    a.sort_indices()
    return pymetis.CSRAdjacency(adj_starts=a.indptr, adjacent=a.indices)


def metis_options():
    """METIS options with the fixed seed (:data:`_METIS_SEED`)."""
    import pymetis

    return pymetis.Options(seed=_METIS_SEED)
