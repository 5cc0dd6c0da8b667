"""Tests of random leaders, hop-count clusters and the abstracted graph (Funiak et al. 2008 §IV-C, §V-A)."""

import numpy as np
from scipy import sparse
from scipy.sparse.csgraph import shortest_path

from decentral.ensemble.abstraction import abstract_graph, choose_leaders, elect_leaders, hop_clusters


def test_each_node_joins_a_nearest_leader(lattice):
    """Every node's hop count equals the BFS distance to the nearest leader, and that leader is its own."""
    prob, _, _ = lattice(2, (12, 10))
    A = prob.adjacency()
    leaders = choose_leaders(prob.n, 7, np.random.default_rng(1))
    cl = hop_clusters(A, leaders)
    D = shortest_path(A, unweighted=True, indices=leaders)
    np.testing.assert_array_equal(cl.hops, D.min(axis=0).astype(int))
    np.testing.assert_array_equal(D[cl.cluster, np.arange(prob.n)], cl.hops)


def test_ties_go_to_smallest_leader_id():
    """A node equidistant from two leaders joins the one with the smaller id."""
    # path 0 - 1 - 2 with leaders 0 and 2: node 1 is at one hop from both
    A = sparse.csr_matrix(np.array([[0, 1, 0], [1, 0, 1], [0, 1, 0]], float))
    cl = hop_clusters(A, np.array([2, 0]))
    assert cl.leader_of[1] == 0


def test_abstract_graph_preserves_degrees(lattice):
    """Row sums of the abstracted graph equal the summed degrees of each cluster's members."""
    prob, _, _ = lattice(2, (9, 9))
    A = prob.adjacency()
    cl = hop_clusters(A, choose_leaders(prob.n, 5, np.random.default_rng(2)))
    W = abstract_graph(A, cl.cluster, 5)
    deg = np.asarray(A.sum(axis=1)).ravel()
    np.testing.assert_allclose(np.asarray(W.sum(axis=1)).ravel(), np.bincount(cl.cluster, deg, 5))


def test_election_uses_the_given_stream_only():
    """The same generator state elects the same leaders; at least one is always elected."""
    a = elect_leaders(1000, 0.01, np.random.default_rng(7))
    b = elect_leaders(1000, 0.01, np.random.default_rng(7))
    np.testing.assert_array_equal(a, b)
    assert elect_leaders(5, 1e-9, np.random.default_rng(0)).size == 1
