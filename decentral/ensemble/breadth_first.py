"""Breadth-first placement: an initial estimate from a spanning traversal (Funiak et al. 2008 §III-B).

Starting from a root module at the origin with the identity orientation, modules are placed one
breadth-first layer at a time. A module of the new layer gets the mean of the centres its placed
neighbours predict for it (neighbour k predicts c_k + 2 R_k z_kj under the model of eq. 1), and the
orientation that best maps its own observations of those neighbours onto their directions (a
per-module Kabsch fit). This is the "local heuristic" of Algorithm 1 line 2 and the first step of
the incremental baseline.
"""

from __future__ import annotations

import numpy as np
from scipy import sparse

from decentral.ensemble.abstraction import csr_neighbours
from decentral.ensemble.problem import EnsembleProblem
from decentral.ensemble.rotation import project_to_rotation

__all__ = ["bfs_layers", "place_breadth_first", "LayerPlacer"]


def bfs_layers(adjacency: sparse.csr_matrix, root: int) -> list[np.ndarray]:
    """Breadth-first layers (list of node arrays) of the component of ``root`` (layer 0 = [root])."""
    A = sparse.csr_matrix(adjacency)
    seen = np.zeros(A.shape[0], dtype=bool)
    seen[root] = True
    layers = [np.array([root], dtype=np.int64)]
    while True:
        _, nbr = csr_neighbours(A, layers[-1])
        nbr = np.unique(nbr[~seen[nbr]])
        if nbr.size == 0:
            return layers
        seen[nbr] = True
        layers.append(nbr)


def place_breadth_first(problem: EnsembleProblem, root: int | None = None,
                        after_layer=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Place every module reachable from ``root`` (default: a module of highest degree).

    ``after_layer(pos, rot, placed)``, if given, runs after each breadth-first layer is placed and
    may update ``pos`` and ``rot`` in place (the incremental baseline refines there).

    Returns
    -------
    position : ndarray, shape (n, dim)
    rotation : ndarray, shape (n, dim, dim)
    placed : ndarray of bool, shape (n,)
        False for modules not reachable from the root (left at the origin, identity orientation).
    """
    n, d = problem.n, problem.dim
    A = problem.adjacency()
    if root is None:
        root = int(np.argmax(np.diff(A.indptr))) if n else 0
    pos = np.zeros((n, d))
    rot = np.tile(np.eye(d), (n, 1, 1))
    placed = np.zeros(n, dtype=bool)
    if n == 0:
        return pos, rot, placed
    placed[root] = True
    placer = LayerPlacer(problem)
    for layer in bfs_layers(A, root)[1:]:
        placer.place(pos, rot, placed, layer)
        if after_layer is not None:
            after_layer(pos, rot, placed)
    return pos, rot, placed


class LayerPlacer:
    """Places a set of new modules from their already placed neighbours (in place, vectorized).

    A new module m gets the mean of the centres its placed neighbours k predict for it,
    c_k + 2 R_k z_km (Funiak et al. 2008 eq. 1 with zero residual), and the orientation that best maps its
    own observations z_mk onto the directions (c_k - c_m)/2 (per-module Kabsch fit).
    """

    def __init__(self, problem: EnsembleProblem):
        self.problem = problem
        n, j = problem.n, problem.j
        self.by_j = np.argsort(j, kind="stable")
        self.starts = np.searchsorted(j[self.by_j], np.arange(n + 1))
        self.rev = _reverse_index(problem)

    def place(self, pos: np.ndarray, rot: np.ndarray, placed: np.ndarray, layer: np.ndarray) -> None:
        """Place modules ``layer`` (each must have a placed neighbour) and mark them placed."""
        prob = self.problem
        n, d = prob.n, prob.dim
        i, j, z = prob.i, prob.j, prob.z
        starts, by_j = self.starts, self.by_j
        counts = starts[layer + 1] - starts[layer]
        offs = np.cumsum(counts) - counts
        e = by_j[np.arange(counts.sum()) - np.repeat(offs, counts) + np.repeat(starts[layer], counts)]
        e = e[placed[i[e]]]  # observations k -> new module, k already placed
        k, m = i[e], j[e]
        pred = pos[k] + 2.0 * np.einsum("eab,eb->ea", rot[k], z[e])
        cnt = np.maximum(np.bincount(m, minlength=n)[layer], 1)
        for a in range(d):
            pos[layer, a] = np.bincount(m, pred[:, a], n)[layer] / cnt
        back = self.rev[e]
        target = 0.5 * (pos[k] - pos[m])
        M = np.zeros((layer.size, d, d))
        local = np.searchsorted(layer, m) if np.all(np.diff(layer) > 0) else _positions(layer, m)
        for a in range(d):
            for b in range(d):
                M[:, a, b] = np.bincount(local, target[:, a] * z[back, b], layer.size)
        rot[layer] = project_to_rotation(M)
        placed[layer] = True


def _positions(layer: np.ndarray, m: np.ndarray) -> np.ndarray:
    order = np.argsort(layer)
    return order[np.searchsorted(layer[order], m)]


def _reverse_index(problem: EnsembleProblem) -> np.ndarray:
    """Index of the reverse observation (j, i) of every observation (i, j)."""
    n = problem.n
    key = problem.i * n + problem.j
    order = np.argsort(key)
    rkey = problem.j * n + problem.i
    return order[np.searchsorted(key[order], rkey)]
