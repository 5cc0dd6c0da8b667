"""Graph abstraction by random leaders and hop-count clustering (Funiak et al. 2008 §IV-C and §V-A).

Each module elects itself a leader with a small probability (or a fixed number of leaders is
drawn); every module then joins the nearest leader by hop count, ties going to the leader with the
smallest id, so that a distributed run that breaks ties the same way reproduces the clusters
exactly. The abstracted graph has one node per cluster; its edge weights count the observation
pairs between clusters and its self-loops the pairs inside a cluster, so normalized cut on it sees
the same ``assoc`` as on the original graph.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse

from decentral.errors import InputError

__all__ = ["Clustering", "elect_leaders", "choose_leaders", "hop_clusters", "abstract_graph", "csr_neighbours"]


@dataclass(frozen=True)
class Clustering:
    """Hop-count clusters around leaders.

    Attributes
    ----------
    leaders : ndarray of int, shape (k,)
        Leader node ids, increasing.
    cluster : ndarray of int, shape (n,)
        Index into ``leaders`` of each node's cluster; -1 for nodes no leader reaches.
    hops : ndarray of int, shape (n,)
        Hop distance to the node's leader; -1 where unreached.
    """

    leaders: np.ndarray
    cluster: np.ndarray
    hops: np.ndarray

    @property
    def leader_of(self) -> np.ndarray:
        """Leader node id (n,) of each node (-1 where unreached)."""
        return np.where(self.cluster >= 0, self.leaders[np.maximum(self.cluster, 0)], -1)


def elect_leaders(n: int, probability: float, rng: np.random.Generator) -> np.ndarray:
    """Each of ``n`` nodes becomes a leader independently with ``probability`` (at least one leader).

    Returns increasing node ids (k,). Draws exactly ``n`` uniforms (plus one integer if nobody was
    elected), so node i's decision is ``rng.random(n)[i] < probability``.
    """
    if not 0.0 < probability <= 1.0:
        raise InputError(f"must be in (0, 1], got {probability}", field="probability")
    leaders = np.flatnonzero(rng.random(n) < probability)
    if leaders.size == 0:
        leaders = np.array([int(rng.integers(n))])
    return leaders.astype(np.int64)


def choose_leaders(n: int, count: int, rng: np.random.Generator) -> np.ndarray:
    """``min(count, n)`` distinct leaders drawn uniformly from ``0..n-1``, increasing."""
    count = max(1, min(int(count), n))
    return np.sort(rng.choice(n, size=count, replace=False)).astype(np.int64)


def csr_neighbours(adjacency: sparse.csr_matrix, nodes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All (source, neighbour) pairs out of ``nodes`` in a CSR graph, vectorized.

    Returns ``src`` and ``nbr`` of equal length: ``nbr[k]`` is a neighbour of ``src[k]``.
    """
    indptr, indices = adjacency.indptr, adjacency.indices
    starts = indptr[nodes]
    counts = indptr[nodes + 1] - starts
    total = int(counts.sum())
    offs = np.cumsum(counts) - counts
    idx = np.arange(total) - np.repeat(offs, counts) + np.repeat(starts, counts)
    return np.repeat(nodes, counts), indices[idx].astype(np.int64)


def hop_clusters(adjacency: sparse.spmatrix, leaders: np.ndarray) -> Clustering:
    """Assign every node to its nearest leader by hop count (multi-source BFS, O(E)).

    Parameters
    ----------
    adjacency : sparse matrix, shape (n, n)
        Symmetric contact graph.
    leaders : ndarray of int, shape (k,)
        Distinct leader node ids.

    Notes
    -----
    Ties (two leaders at the same hop count) go to the leader with the smallest id; within a BFS
    round a node takes the smallest leader id offered by any of its neighbours that joined in the
    previous round, which is what a synchronous distributed flood does.
    """
    A = sparse.csr_matrix(adjacency)
    n = A.shape[0]
    leaders = np.unique(np.asarray(leaders, dtype=np.int64))
    if leaders.size == 0 or leaders.min() < 0 or leaders.max() >= n:
        raise InputError("leaders must be node ids in range", field="leaders")
    label = np.full(n, -1, dtype=np.int64)  # leader node id
    hops = np.full(n, -1, dtype=np.int64)
    label[leaders] = leaders
    hops[leaders] = 0
    frontier = leaders
    h = 0
    while frontier.size:
        src, nbr = csr_neighbours(A, frontier)
        lab = label[src]
        free = label[nbr] < 0
        nbr, lab = nbr[free], lab[free]
        if nbr.size == 0:
            break
        order = np.lexsort((lab, nbr))
        nbr, lab = nbr[order], lab[order]
        first = np.ones(nbr.size, dtype=bool)
        first[1:] = nbr[1:] != nbr[:-1]
        h += 1
        frontier = nbr[first]
        label[frontier] = lab[first]
        hops[frontier] = h
    cluster = np.where(label >= 0, np.searchsorted(leaders, np.maximum(label, 0)), -1)
    return Clustering(leaders, cluster.astype(np.int64), hops)


def abstract_graph(adjacency: sparse.spmatrix, cluster: np.ndarray, k: int) -> sparse.csr_matrix:
    """Cluster graph (k, k): W[a, b] = observation pairs between clusters a, b; W[a, a] = 2 x inside.

    Nodes with ``cluster == -1`` are ignored. Row sums equal the summed degrees of each cluster.
    """
    A = sparse.coo_matrix(adjacency)
    cluster = np.asarray(cluster, dtype=np.int64)
    keep = (cluster[A.row] >= 0) & (cluster[A.col] >= 0)
    W = sparse.csr_matrix((A.data[keep], (cluster[A.row[keep]], cluster[A.col[keep]])), shape=(k, k))
    W.sum_duplicates()
    return W
