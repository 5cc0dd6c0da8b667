"""Least-squares module centres for fixed orientations: the contact graph's Laplacian, factorized once (:class:`LaplacianSolver`)."""

from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.sparse.linalg import splu

from decentral.ensemble.ordering import nested_dissection

__all__ = ["LaplacianSolver"]


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
