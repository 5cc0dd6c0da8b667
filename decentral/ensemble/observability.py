"""What the observations of a 3D ensemble cannot fix: hinges (Funiak et al. 2008, eq. 1-2).

One observation pair (i, j) ties module j to module i through the two residuals of eq. 1,

.. math::

    r_{ij} = R_i z_{ij} - \\tfrac12 (c_j - c_i), \\qquad r_{ji} = R_j z_{ji} - \\tfrac12 (c_i - c_j).

Turn module j and everything beyond it rigidly by a rotation Q about the line through c_i and c_j
(c_k -> c_j + Q (c_k - c_j), R_k -> Q R_k): r_ij does not change (c_j and R_i stay), every residual
beyond j is turned by Q, and ``|Q R_j z_ji - w / 2| = |R_j z_ji - w / 2|`` for w = c_i - c_j, which
Q leaves fixed. So the likelihood (eq. 2) is exactly the same for every angle, with or without
noise: where one observation pair is all that joins two parts of a 3D ensemble, the rotation of
one part about that pair's line is unobservable, and any maximum-likelihood estimate may have the
parts turned against each other by any angle (each part is still right in itself, so the local
RMS does not see it). In 2D the pair fixes the relative rotation, and nothing is lost.

A single file of modules (a rod one module thick) is a chain of such hinges.
"""

from __future__ import annotations

import networkx as nx
import numpy as np
from scipy import sparse

from decentral.ensemble.problem import EnsembleProblem, connected_components

__all__ = ["hinge_pairs", "hinged_parts"]


def hinge_pairs(problem: EnsembleProblem) -> np.ndarray:
    """Observation pairs (H, 2) about which part of a 3D ensemble can turn freely; empty in 2D.

    A hinge is a bridge of the contact graph (the only observation pair between two parts) with
    at least two modules on each side; a bridge to a single module is left out, since turning
    that module about the line through both centres moves no centre. Rows are ``(i, j)`` with
    ``i < j``, in increasing order. Cost: one pass of :func:`networkx.bridges` over the contact
    graph (about 1 s at 20,000 3D modules).
    """
    if problem.dim != 3:
        return np.zeros((0, 2), dtype=np.int64)
    pairs = problem.pairs()
    graph = nx.Graph()
    graph.add_nodes_from(range(problem.n))
    graph.add_edges_from(pairs.tolist())
    degree = np.bincount(pairs.ravel(), minlength=problem.n)
    # a bridge whose ends both have another neighbour has a part of >= 2 modules on each side
    found = [sorted(e) for e in nx.bridges(graph) if degree[e[0]] > 1 and degree[e[1]] > 1]
    if not found:
        return np.zeros((0, 2), dtype=np.int64)
    out = np.asarray(found, dtype=np.int64)
    return out[np.lexsort((out[:, 1], out[:, 0]))]


def hinged_parts(problem: EnsembleProblem, hinges: np.ndarray) -> np.ndarray:
    """Label (n,) of the part each module is in once the ``hinges`` (H, 2) are cut; 0 is the largest part.

    Each part is held together by more than single contacts; the parts other than 0 are what may
    turn against the largest (ties go to the part of the smallest module id).
    """
    pairs = problem.pairs()
    cut = np.isin(pairs[:, 0] * problem.n + pairs[:, 1], hinges[:, 0] * problem.n + hinges[:, 1])
    kept = pairs[~cut]
    graph = sparse.coo_matrix((np.ones(len(kept)), (kept[:, 0], kept[:, 1])), shape=(problem.n, problem.n))
    _, label = connected_components(graph.tocsr())
    order = np.argsort(-np.bincount(label), kind="stable")  # largest first
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    return rank[label]
