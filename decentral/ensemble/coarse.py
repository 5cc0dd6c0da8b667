"""Two-level initial inverse Hessian for the L-BFGS refiner: the Laplacian plus rigid motions of clusters.

The L-BFGS refiner (:mod:`decentral.ensemble.refine`) minimizes F(c) = min_R cost(c, R) over the
centres with 4 L^-1 as its initial inverse Hessian, L the contact-graph Laplacian. That is the exact
inverse of the position block for *fixed* orientations, so it treats a cluster turning as a whole,
its modules' orientations turning with it, as if the observations inside the cluster kept their world
directions: it charges every internal contact for a motion that costs only the contacts on the
cluster's boundary. Smooth collective modes built from such motions (a 3D solid twisting about the
thin rods between its chambers) are then the soft directions that L-BFGS has to learn one curvature
pair at a time, and there are more of them the larger the ensemble.

This module adds them back as a coarse space, as two-level domain-decomposition and deflation methods
do. The ensemble is cut into K clusters of about ``size`` modules (METIS k-way partition of the
contact graph); a coarse vector holds a small rigid motion (t_k, w_k) per cluster, which moves the
centres by

    dc_i = t_k + w_k x (c_i - g_k)        (P, shape (n d, m K); m = 3 in 2D, 6 in 3D)

with g_k the cluster's centroid, and turns its modules' orientations by w_k. Internal observations
are unchanged by such a motion up to the rotation of their residual, so the Gauss-Newton curvature
of the likelihood over coarse vectors is

    E = J^T J,   J = dr/d(t, w) = Jrot - B P     (Funiak et al. 2008 eq. (3), r_e = R_i z_e - (c_j - c_i)/2)

with Jrot the residuals' change from the turning orientations and B the (scaled) incidence matrix;
G = -B^T J approximates the reduced Hessian times P. The initial inverse Hessian is the deflated,
symmetric two-level operator

    H0 = P E^+ P^T + (I - P E^+ G^T) 4 L^-1 (I - G E^+ P^T),

the coarse motions solved exactly (in their Gauss-Newton model) and the Laplacian left to the rest.
Held modules (the gauge anchor of each component, a seam's ring) have zero rows in P, so their centres
never move; modules whose orientation is held do not turn. E is singular along motions that cost
nothing (a whole component turning about its held anchor); its pseudo-inverse drops them.

Measured on Algorithm 1's top refinements (clusters of 500 modules, same starts): ``triple3d`` comes
to a cost within 0.001 sigma^2 of the optimum in 100 instead of 119 iterations at 5,000 modules and
in 109 instead of 197 at 20,000, and the default stopping rule ends after 164 instead of 187 and
141 instead of 216 iterations; 2D ``triple`` at 100,000 modules takes 40 instead of 73. The saving
grows with the ensemble, as the soft modes multiply (docs/ensemble.md, scalability).
"""

from __future__ import annotations

import numpy as np
from scipy import sparse

from decentral.ensemble.ordering import metis_graph, metis_options
from decentral.ensemble.rotation import skew

__all__ = ["TwoLevelInverse", "cluster_labels"]

#: eigenvalues of E below this fraction of its largest are treated as zero (motions that cost nothing)
_PINV_RTOL = 1e-10


def cluster_labels(adjacency: sparse.spmatrix, size: int) -> np.ndarray:
    """METIS k-way partition of a contact graph into clusters of about ``size`` modules (seeded as the
    orderings are, :func:`~decentral.ensemble.ordering.metis_options`).

    Parameters
    ----------
    adjacency : scipy.sparse matrix, shape (n, n)
        The contact graph (any symmetric or directed pattern; symmetrized here, diagonal ignored).
    size : int
        Target modules per cluster (>= 1).

    Returns
    -------
    labels : ndarray of int, shape (n,)
        Cluster of each module, 0..K-1 with K = max(round(n / size), 1).
    """
    import pymetis

    n = adjacency.shape[0]
    k = max(int(round(n / max(int(size), 1))), 1)
    if k == 1:
        return np.zeros(n, dtype=np.int64)
    _, parts = pymetis.part_graph(k, adjacency=metis_graph(adjacency), options=metis_options())
    return np.asarray(parts, dtype=np.int64)


def _motion_blocks(rel: np.ndarray) -> np.ndarray:
    """d c_i / d(t, w) of a rigid motion about the centroid, (n, d, m), for offsets ``rel`` (n, d)."""
    n, d = rel.shape
    if d == 2:
        out = np.zeros((n, 2, 3))
        out[:, :, :2] = np.eye(2)
        out[:, 0, 2], out[:, 1, 2] = -rel[:, 1], rel[:, 0]  # w x rel for a scalar (planar) w
        return out
    out = np.zeros((n, 3, 6))
    out[:, :, :3] = np.eye(3)
    out[:, :, 3:] = -skew(rel)  # w x rel = -[rel]x w
    return out


def _turn_blocks(v: np.ndarray) -> np.ndarray:
    """d (Q v) / d w at Q = I for vectors ``v`` (E, d): (E, d, 1) in 2D (planar w), (E, 3, 3) in 3D."""
    if v.shape[1] == 2:
        return np.stack([-v[:, 1], v[:, 0]], 1)[:, :, None]
    return -skew(v)


def _block_rows(blocks: np.ndarray, cluster: np.ndarray, m: int, n_cols: int, first: int = 0) -> sparse.csr_matrix:
    """Sparse (len * d, n_cols) matrix whose row (r, a) holds ``blocks[r, a]`` (q values) at columns
    m * cluster[r] + first + 0..q-1."""
    count, d, q = blocks.shape
    cols = np.broadcast_to((m * cluster + first)[:, None, None] + np.arange(q), blocks.shape)
    indptr = np.arange(0, count * d * q + 1, q)
    return sparse.csr_matrix((blocks.ravel(), cols.ravel(), indptr), shape=(count * d, n_cols))


def _curvature_and_gradient_change(Jrot: sparse.csr_matrix, incidence: sparse.spmatrix, P: sparse.csr_matrix,
                                   PT: sparse.csr_matrix, free: np.ndarray) -> tuple[np.ndarray, sparse.csr_matrix]:
    """E = J^T J (dense, (m K, m K)) and G = -Bd^T J (sparse, (n d, m K), zero on held centres) for
    J = Jrot - Bd P, Bd = B kron I_d, without forming J (12 entries per residual row in 3D): with
    W = Bd^T Jrot and Bd^T Bd = (B^T B) kron I_d,

        G = (B^T B kron I) P - W,    E = Jrot^T Jrot - P^T W - W^T P + P^T (B^T B kron I) P.
    """
    d = P.shape[0] // incidence.shape[1]
    Bd = sparse.kron(incidence, sparse.identity(d), format="csr")
    W = (Bd.T @ Jrot).tocsr()
    del Bd
    LP = (sparse.kron((incidence.T @ incidence).tocsr(), sparse.identity(d), format="csr") @ P).tocsr()
    curvature = (Jrot.T @ Jrot - PT @ W - W.T @ P + PT @ LP).toarray()
    G = sparse.diags(np.repeat(free, d).astype(float)) @ (LP - W)  # the gradient lives on the free centres
    G.eliminate_zeros()
    return curvature, G.tocsr()


class TwoLevelInverse:
    """The two-level operator H0 of the module docstring, for vectors (n, d) in module radii.

    Parameters
    ----------
    i, j : ndarray of int, shape (E,)
        Observations (observer, observed).
    incidence : scipy.sparse matrix, shape (E, n)
        B, with B c = (c_j - c_i) / 2 per observation.
    position : ndarray, shape (n, d)
        Centres at which the coarse space is built (module radii).
    turned : ndarray, shape (E, d)
        R_i z_e at those centres' orientations (module radii).
    labels : ndarray of int, shape (n,)
        Cluster of each module (:func:`cluster_labels`).
    free : ndarray of bool, shape (n,)
        Modules whose centre may move.
    turning : ndarray of bool, shape (n,)
        Modules whose orientation may turn.
    fine : callable
        v (n, d) -> 4 L^-1 v on the free modules (zero on the held ones).

    Attributes
    ----------
    P : scipy.sparse.csr_matrix, shape (n d, m K)
        Centre displacements (row-major (n, d)) of the clusters' rigid motions (t_k, w_k).
    curvature : ndarray, shape (m K, m K)
        E = J^T J, the Gauss-Newton curvature of the likelihood over those motions.
    """

    def __init__(self, i: np.ndarray, j: np.ndarray, incidence: sparse.spmatrix, position: np.ndarray,
                 turned: np.ndarray, labels: np.ndarray, free: np.ndarray, turning: np.ndarray, fine):
        n, d = position.shape
        k = int(labels.max()) + 1
        m = 3 if d == 2 else 6
        self.shape, self.fine = (n, d), fine
        centroid = np.zeros((k, d))
        np.add.at(centroid, labels, position)
        centroid /= np.maximum(np.bincount(labels, minlength=k), 1)[:, None]
        blocks = _motion_blocks(position - centroid[labels])
        blocks[~free] = 0.0  # held centres do not move
        self.P = _block_rows(blocks, labels, m, m * k)
        self.P.eliminate_zeros()  # a motion block is half zeros
        self.PT = self.P.T.tocsr()
        turn = _turn_blocks(turned)
        turn[~turning[i]] = 0.0  # held orientations do not turn
        Jrot = _block_rows(turn, labels[i], m, m * k, first=d)  # the turning columns (t_k come first)
        Jrot.eliminate_zeros()
        self.curvature, G = _curvature_and_gradient_change(Jrot, incidence, self.P, self.PT, free)
        self.G, self.GT = G, G.T.tocsr()
        w, V = np.linalg.eigh(self.curvature)
        keep = w > _PINV_RTOL * max(float(w.max()), 1e-300)
        self.V, self.w = V[:, keep], w[keep]

    def _coarse_solve(self, b: np.ndarray) -> np.ndarray:
        return self.V @ ((self.V.T @ b) / self.w)

    def __call__(self, v: np.ndarray) -> np.ndarray:
        """H0 v for v (n, d), zero on held centres."""
        flat = v.ravel()
        coarse = self._coarse_solve(self.PT @ flat)
        smooth = self.fine((flat - self.G @ coarse).reshape(self.shape)).ravel()
        out = smooth + self.P @ (coarse - self._coarse_solve(self.GT @ smooth))
        return out.reshape(self.shape)
