"""What a group leader computes from aggregated data (pure functions, no messaging).

:func:`cut_clusters` is Algorithm 1 line 4 on the aggregated abstract graph (the normalized cut
itself is :func:`decentral.ensemble.normalized_cut`); :func:`plan_merge` is lines 7-10 from the
aggregated alignment statistics, in the same order as :func:`decentral.ensemble.hierarchical.merge_parts`
(largest part first, then the part with most observations into what is merged), using
:meth:`decentral.ensemble.AlignmentStats.solve` for each closed-form alignment (Funiak et al. 2008 eq. 5).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.sparse.csgraph import connected_components

from decentral.ensemble import AlignmentStats, RigidTransform, normalized_cut

__all__ = ["CutPlan", "cut_clusters", "moved_target", "plan_merge"]


@dataclass(frozen=True)
class CutPlan:
    """A group's split into parts.

    Attributes
    ----------
    cluster_ids : ndarray of int, shape (k,)
        Cluster leader ids, increasing.
    cluster_part : ndarray of int, shape (k,)
        Part index of each cluster.
    part_leader : ndarray of int, shape (P,)
        Smallest module id of each part (its leader); parts are ordered by it.
    part_size : ndarray of int, shape (P,)
    value : float
        Ncut of the abstract graph (eq. 4).
    """

    cluster_ids: np.ndarray
    cluster_part: np.ndarray
    part_leader: np.ndarray
    part_size: np.ndarray
    value: float


def cut_clusters(ea, eb, ew, cid, csize, cmin) -> CutPlan:
    """Normalized cut of the aggregated abstract graph and the connected parts of its two sides.

    Clusters are indexed by increasing leader id (with one module per cluster this is exactly the
    subproblem order of the centralized algorithm, so the cut is the same). A side of the cut that
    is not connected gives several parts, as in the centralized algorithm.
    """
    cid = np.asarray(cid, dtype=np.int64)
    order = np.argsort(cid)
    cid, csize, cmin = cid[order], np.asarray(csize)[order], np.asarray(cmin)[order]
    k = cid.size
    a = np.searchsorted(cid, ea)
    b = np.searchsorted(cid, eb)
    W = sparse.csr_matrix((np.asarray(ew, float), (a, b)), shape=(k, k))
    res = normalized_cut(W)
    side = res.in_a.astype(np.int64)
    same = side[a] == side[b]
    keep = same & (a != b)
    g = sparse.csr_matrix((np.ones(int(keep.sum())), (a[keep], b[keep])), shape=(k, k))
    _, comp = connected_components(g, directed=False)
    P = int(comp.max()) + 1
    leader = np.full(P, np.iinfo(np.int64).max, dtype=np.int64)
    np.minimum.at(leader, comp, cmin)
    size = np.bincount(comp, weights=csize, minlength=P).astype(np.int64)
    rank = np.argsort(np.argsort(leader))  # parts ordered by their smallest module id
    part = rank[comp]
    return CutPlan(cid, part.astype(np.int64), np.sort(leader), size[np.argsort(leader)], res.value)


def moved_target(stats: AlignmentStats, T: RigidTransform) -> AlignmentStats:
    """Statistics of the pairs {(R p + t, q)} given those of {(p, q)}: the target side moved by ``T``."""
    Rp = T.R @ stats.sum_p
    return AlignmentStats(
        stats.count,
        Rp + stats.count * T.t,
        stats.sum_q,
        T.R @ stats.sum_pq + np.outer(T.t, stats.sum_q),
        float(stats.sum_pp + 2.0 * T.t @ Rp + stats.count * T.t @ T.t),
        stats.sum_qq,
    )


def plan_merge(parts: np.ndarray, sizes: np.ndarray, pa, pb, stats, links) -> dict[int, RigidTransform]:
    """Transforms taking each part's frame into the frame of the largest part.

    Parameters
    ----------
    parts : ndarray of int, shape (P,)
        Part leader ids, increasing (the part order).
    sizes : ndarray of int, shape (P,)
    pa, pb : ndarray of int, shape (m,)
        Ordered part pairs with observations from ``pa`` to ``pb``.
    stats : ndarray, shape (m, 3 + 2 d + d^2)
        Alignment statistics of the points of each ``pa -> pb`` observation, ``p`` in ``pa``'s frame
        and ``q`` in ``pb``'s (from :func:`decentral.ensemble.merge_point_pairs`).
    links : ndarray of int, shape (m,)
        Observations from ``pa`` to ``pb``.
    """
    parts = np.asarray(parts, dtype=np.int64)
    P = parts.size
    ia, ib = np.searchsorted(parts, pa), np.searchsorted(parts, pb)
    table = {(int(x), int(y)): AlignmentStats.from_array(s) for x, y, s in zip(ia, ib, np.asarray(stats))}
    count = np.zeros((P, P))
    np.add.at(count, (ia, ib), np.asarray(links, float))
    d = next(iter(table.values())).dim if table else 2
    merged = np.zeros(P, dtype=bool)
    ref = int(np.argmax(sizes))
    merged[ref] = True
    T: dict[int, RigidTransform] = {ref: RigidTransform(np.eye(d), np.zeros(d))}
    while not merged.all():
        into = count[merged].sum(axis=0)
        into[merged] = -1
        p = int(np.argmax(into))
        total = AlignmentStats.zero(d)
        for a in np.flatnonzero(merged):
            s = table.get((int(a), p))
            if s is not None:
                # Funiak et al. 2008 eq. (5): the merged side's points move with their part's transform
                total = total + moved_target(s, T[int(a)])
        T[p] = total.solve()
        merged[p] = True
    return {int(parts[p]): t for p, t in T.items()}
