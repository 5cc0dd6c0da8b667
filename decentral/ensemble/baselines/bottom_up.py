"""Bottom-up merging of clusters in order of algebraic connectivity (Funiak et al. 2008 §VI-E (iv)).

The ensemble is first split into small hop-count clusters around random leaders; each is localized
on its own (breadth-first placement and refinement). Then, repeatedly, the pair of adjacent
clusters whose union has the largest algebraic connectivity (second eigenvalue of the normalized
Laplacian of the union's contact graph) is merged by the same closed-form rigid alignment as
Algorithm 1 and refined, until one cluster remains. It differs from Algorithm 1 only in the order of
the merges: greedy from the bottom instead of normalized cuts from the top.
"""

from __future__ import annotations

import numpy as np

from decentral.ensemble.abstraction import abstract_graph, choose_leaders, hop_clusters
from decentral.ensemble.baselines.common import FINAL_REFINE, run_per_component
from decentral.ensemble.hierarchical import LocalizationResult, merge_parts
from decentral.ensemble.ncut import algebraic_connectivity
from decentral.ensemble.breadth_first import place_breadth_first
from decentral.ensemble.problem import EnsembleProblem
from decentral.ensemble.refine import RefineConfig, refine

__all__ = ["MERGE_REFINE", "bottom_up_initial", "bottom_up_localize"]

#: refinement after each merge
MERGE_REFINE = RefineConfig(max_iter=100, gtol=1e-3)


def bottom_up_initial(problem: EnsembleProblem, rng: np.random.Generator, cluster_size: int = 32,
                      merge_refine: RefineConfig = MERGE_REFINE) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bottom-up merging on a connected problem: centres (n, d), orientations, iterations (n,)."""
    n, d = problem.n, problem.dim
    A = problem.adjacency()
    k = max(1, int(np.ceil(n / cluster_size)))
    cl = hop_clusters(A, choose_leaders(n, k, rng))
    label = cl.cluster.copy()
    pos = np.zeros((n, d))
    rot = np.tile(np.eye(d), (n, 1, 1))
    iters = np.zeros(n)
    for c in range(k):
        nodes = np.flatnonzero(label == c)
        sub = problem.subproblem(nodes)
        p0, r0, _ = place_breadth_first(sub)
        res = refine(sub, p0, r0, merge_refine)
        pos[nodes], rot[nodes] = res.position, res.rotation
        iters[nodes] += res.iterations
    W = abstract_graph(A, label, k).tolil()
    alive = set(range(k))
    score: dict[tuple[int, int], float] = {}

    def union_score(a, b):
        nodes = np.flatnonzero((label == a) | (label == b))
        return algebraic_connectivity(problem.subproblem(nodes).adjacency())

    for a in range(k):
        for b in W.rows[a]:
            if a < b:
                score[(a, b)] = union_score(a, b)
    while len(alive) > 1:
        (a, b) = max(score, key=lambda key: (score[key], -key[0], -key[1]))
        nodes = np.flatnonzero((label == a) | (label == b))
        sub = problem.subproblem(nodes)
        part = (label[nodes] == b).astype(np.int64)
        m0, m1 = nodes[part == 0], nodes[part == 1]
        p, r = merge_parts(sub, part, [(pos[m0], rot[m0]), (pos[m1], rot[m1])])
        res = refine(sub, p, r, merge_refine)
        pos[nodes], rot[nodes] = res.position, res.rotation
        iters[nodes] += res.iterations
        # b joins a
        label[label == b] = a
        alive.discard(b)
        for key in [key for key in score if a in key or b in key]:
            del score[key]
        W[a, :] = W[a, :] + W[b, :]
        W[:, a] = W[:, a] + W[:, b]
        W[b, :] = 0
        W[:, b] = 0
        for c in W.rows[a]:
            if c != a and c in alive:
                score[(min(a, c), max(a, c))] = union_score(a, c)
    return pos, rot, iters


def bottom_up_localize(problem: EnsembleProblem, rng: np.random.Generator, cluster_size: int = 32,
                       refine_config: RefineConfig | None = FINAL_REFINE) -> LocalizationResult:
    """Localize by bottom-up merging (``rng`` draws the initial cluster leaders), then refine."""
    return run_per_component(problem, lambda sub: bottom_up_initial(sub, rng, cluster_size), refine_config,
                             {"method": "bottom_up"})
