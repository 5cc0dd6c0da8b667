"""Tests of the distributed runner (seed 003 §V) against the centralized Algorithm 1."""

import numpy as np
import pytest

from decentral.ensemble import EnsembleProblem, HierarchyConfig, align_points, normcut_localize
from sims.ensembles import EnsembleSpec, generate
from sims.ensembles.distributed import DistributedConfig, run_distributed

#: small leaves so that a small ensemble still has several levels, cuts, merges and refinements
EXACT = HierarchyConfig(leaf_size=6, cut="exact")
ABSTRACT = HierarchyConfig(leaf_size=6, cut="abstract", abstract_size=3)


@pytest.fixture(scope="module")
def problem():
    ens = generate(EnsembleSpec(shape="triple", n=28), np.random.default_rng(11))
    return EnsembleProblem.create(ens.dim, ens.n, ens.radius, ens.i, ens.j, ens.z)


@pytest.fixture(scope="module")
def exact_run(problem):
    return run_distributed(problem, np.random.default_rng(0), DistributedConfig(hierarchy=EXACT, top_gtol=1e-6))


def _aligned_rms(a, b, radius):
    T = align_points(b, a)
    return float(np.sqrt(np.mean(np.sum((T.apply(a) - b) ** 2, axis=1)))) / radius


def test_distributed_gives_the_centralized_answer(problem, exact_run):
    """Same cuts, leaves and merges as Algorithm 1; after alignment the positions agree to 1e-3 radii.

    Both runs stop within a gradient tolerance of the same optimum (centralized 1e-6, distributed
    1e-6 radii); measured differences are ~1e-4 radii, well below the 1e-3 allowed, and far below
    the quantization of the observations (a sensor spacing is ~0.5 radii).
    """
    central = normcut_localize(problem, np.random.default_rng(0), EXACT)
    assert exact_run.levels >= 2
    assert _aligned_rms(exact_run.estimate.position, central.estimate.position, problem.radius) < 1e-3
    assert abs(exact_run.cost - central.cost) <= 1e-6 * max(central.cost, 1e-12) + 1e-12


def test_message_counts_add_up(exact_run):
    """Per-module counts, per-phase counts and the network's own counter give the same total."""
    total = int(exact_run.messages.sum())
    assert total == int(exact_run.phase_messages.sum()) == exact_run.network["total"]["sent"]
    assert len(exact_run.phase_names) == len(exact_run.phase_messages)
    named = dict(zip(exact_run.phase_names, exact_run.phase_messages.tolist()))
    for phase in ("neighbor_detection", "leader_election", "normalized_cut", "leaf_localization",
                  "rigid_alignment", "refinement"):
        assert named[phase] > 0, phase
    assert np.all(exact_run.messages > 0)


def test_neighbour_detection_is_one_message_per_observation(problem, exact_run):
    """Neighbour detection sends exactly one message per directed observation."""
    named = dict(zip(exact_run.phase_names, exact_run.phase_messages.tolist()))
    assert named["neighbor_detection"] == problem.num_observations


def test_abstraction_phase_runs_on_large_groups(problem):
    """With groups above four abstraction sizes, hop-count clustering messages are sent and counted."""
    res = run_distributed(problem, np.random.default_rng(1), DistributedConfig(hierarchy=ABSTRACT, top_gtol=1e-3))
    named = dict(zip(res.phase_names, res.phase_messages.tolist()))
    assert named["graph_abstraction"] > 0
    assert int(res.messages.sum()) == res.network["total"]["sent"]
    assert np.all(np.isfinite(res.estimate.position))


@pytest.mark.slow
def test_lossy_network_gives_the_lossless_answer(problem, exact_run):
    """With 20 % message loss, acknowledged retransmission yields the lossless estimate, with more messages."""
    res = run_distributed(problem, np.random.default_rng(0),
                          DistributedConfig(hierarchy=EXACT, loss=0.2, top_gtol=1e-6))
    assert res.network["drop_reasons"].get("loss", 0) > 0
    assert res.messages.sum() > exact_run.messages.sum()
    assert np.allclose(res.estimate.position, exact_run.estimate.position, atol=1e-12)


@pytest.mark.slow
def test_same_seed_same_messages(problem, exact_run):
    """A run is reproducible: same seed, same per-module message counts and estimate."""
    again = run_distributed(problem, np.random.default_rng(0), DistributedConfig(hierarchy=EXACT, top_gtol=1e-6))
    assert np.array_equal(again.messages, exact_run.messages)
    assert np.array_equal(again.estimate.position, exact_run.estimate.position)


def test_batched_refinement_counts_what_the_per_message_path_counts(problem, exact_run):
    """The batched refinement sends, per module and phase, exactly the per-message path's messages,
    in the same rounds, with the same bytes, and reaches the same estimate."""
    assert exact_run.info["batched"]
    slow = run_distributed(problem, np.random.default_rng(0),
                           DistributedConfig(hierarchy=EXACT, top_gtol=1e-6, batched=False))
    assert not slow.info["batched"]
    assert np.array_equal(slow.messages, exact_run.messages)
    assert np.array_equal(slow.phase_messages, exact_run.phase_messages)
    assert slow.network == exact_run.network
    assert slow.rounds == exact_run.rounds
    assert slow.info["refine_iterations"] == exact_run.info["refine_iterations"]
    assert slow.info["refine_share_rounds"] == exact_run.info["refine_share_rounds"]
    assert np.allclose(slow.estimate.position, exact_run.estimate.position, rtol=0, atol=1e-12)


def test_batched_refinement_matches_on_abstracted_groups(problem):
    """With graph abstraction and the benchmark's loose tolerances the two paths still agree exactly."""
    cfg = dict(hierarchy=ABSTRACT, top_gtol=1e-2, check_every=5)
    fast = run_distributed(problem, np.random.default_rng(3), DistributedConfig(**cfg))
    slow = run_distributed(problem, np.random.default_rng(3), DistributedConfig(**cfg, batched=False))
    assert np.array_equal(slow.messages, fast.messages)
    assert slow.network == fast.network and slow.rounds == fast.rounds
    assert np.allclose(slow.estimate.position, fast.estimate.position, rtol=0, atol=1e-12)

