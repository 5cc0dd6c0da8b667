"""Tests of the Funiak et al. 2008 §VI-E baselines."""

import numpy as np
import pytest

from decentral.ensemble.baselines import (
    bottom_up_localize,
    classical_mds,
    incremental_localize,
    sdp_localize,
)
from decentral.ensemble.baselines.mds import mds_positions
from decentral.ensemble.baselines.sdp import sdp_positions
from decentral.ensemble.metrics import aligned
from decentral.errors import SolverError


def _rms(est, truth, radius):
    return np.sqrt(np.mean(np.sum((aligned(est, truth) - truth) ** 2, axis=1))) / radius


def test_incremental_recovers_noiseless_lattice(lattice):
    """The breadth-first incremental method is exact on noiseless data."""
    prob, x, _ = lattice(2, (9, 8))
    assert _rms(incremental_localize(prob).estimate.position, x, prob.radius) < 1e-6


def test_bottom_up_recovers_noiseless_lattice(lattice):
    """Bottom-up merging by algebraic connectivity is exact on noiseless data."""
    prob, x, _ = lattice(3, (4, 4, 4))
    res = bottom_up_localize(prob, np.random.default_rng(0), cluster_size=10)
    assert _rms(res.estimate.position, x, prob.radius) < 1e-6


def test_mds_of_a_straight_chain_is_exact():
    """On a chain, hop counts are exact distances, so classical MDS recovers it up to rigid motion."""
    from decentral.ensemble.problem import EnsembleProblem

    n = 12
    i = np.r_[np.arange(n - 1), np.arange(1, n)]
    j = np.r_[np.arange(1, n), np.arange(n - 1)]
    z = np.where((j > i)[:, None], [[1.0, 0.0]], [[-1.0, 0.0]])
    prob = EnsembleProblem.create(2, n, 1.0, i, j, z)
    truth = np.stack([2.0 * np.arange(n), np.zeros(n)], 1)
    assert _rms(mds_positions(prob), truth, 1.0) < 1e-6


def test_mds_then_refinement_reaches_the_lattice(lattice):
    """MDS followed by the likelihood refinement recovers a noiseless lattice."""
    prob, x, _ = lattice(2, (7, 7))
    assert _rms(classical_mds(prob).estimate.position, x, prob.radius) < 1e-4


def test_sdp_spreads_but_keeps_neighbours_within_contact(lattice):
    """The regularized SDP keeps every observed pair within the contact spacing (its constraint)."""
    prob, x, _ = lattice(2, (6, 6))
    pos, facts = sdp_positions(prob)
    P = prob.pairs()
    assert facts["status"] in ("optimal", "optimal_inaccurate")
    # the rank-2 projection can only shorten distances
    assert np.linalg.norm(pos[P[:, 0]] - pos[P[:, 1]], axis=1).max() <= 2 * prob.radius * (1 + 1e-3)


def test_sdp_then_refinement_reaches_the_lattice(lattice):
    """SDP followed by the likelihood refinement recovers a noiseless lattice."""
    prob, x, _ = lattice(2, (6, 6))
    assert _rms(sdp_localize(prob).estimate.position, x, prob.radius) < 1e-4


def test_sdp_size_guard_raises_plainly(lattice):
    """A component above the guard raises SolverError saying it is too large, before any solving."""
    prob, _, _ = lattice(2, (6, 6))
    with pytest.raises(SolverError, match="limited to 20 modules"):
        sdp_localize(prob, max_nodes=20)
