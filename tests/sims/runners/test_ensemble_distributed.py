"""Tests of the distributed runner (Funiak et al. 2008 §V) against the centralized Algorithm 1."""

import numpy as np
import pytest

from decentral.ensemble import EnsembleProblem, HierarchyConfig, RefineConfig, align_points, normcut_localize
from sims.simulation.ensembles import EnsembleSpec, generate
from sims.runners.ensemble_distributed import DistributedConfig, run_distributed

#: small leaves so that a small ensemble still has several levels, cuts, merges and refinements
EXACT = HierarchyConfig(leaf_size=6, cut="exact")
ABSTRACT = HierarchyConfig(leaf_size=6, cut="abstract", abstract_size=3)


@pytest.fixture(scope="module")
def problem():
    ens = generate(EnsembleSpec(shape="triple", n=28), np.random.default_rng(11))
    return EnsembleProblem.create(ens.dim, ens.n, ens.radius, ens.i, ens.j, ens.z)


@pytest.fixture(scope="module")
def small():
    ens = generate(EnsembleSpec(shape="triple", n=16), np.random.default_rng(4))
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



def _both_paths(problem, hierarchy, seed, loss=0.0):
    """The same run through the batched refinement and through the per-message path (the benchmark's
    loose tolerances, so that the per-message run stays cheap)."""
    h = HierarchyConfig(leaf_size=hierarchy.leaf_size, cut=hierarchy.cut, abstract_size=hierarchy.abstract_size,
                        level_refine=RefineConfig(max_iter=100, gtol=0.01))
    cfg = dict(hierarchy=h, top_gtol=1e-2, check_every=5, loss=loss)
    fast = run_distributed(problem, np.random.default_rng(seed), DistributedConfig(**cfg))
    slow = run_distributed(problem, np.random.default_rng(seed), DistributedConfig(**cfg, batched=False))
    return fast, slow


@pytest.mark.parametrize("hierarchy", [EXACT, ABSTRACT], ids=["exact", "abstract"])
def test_batched_refinement_counts_what_the_per_message_path_counts(problem, hierarchy):
    """The batched refinement sends, per module and phase, exactly the per-message path's messages,
    in the same rounds and iterations, with the same bytes, and reaches the same estimate."""
    fast, slow = _both_paths(problem, hierarchy, 3)
    assert fast.info["batched"] and not slow.info["batched"]
    assert fast.levels >= 2 and sum(fast.info["refine_iterations"].values()) > 0
    assert np.array_equal(slow.messages, fast.messages)
    assert np.array_equal(slow.phase_messages, fast.phase_messages)
    assert slow.network == fast.network
    assert slow.rounds == fast.rounds
    assert slow.info["refine_iterations"] == fast.info["refine_iterations"]
    assert slow.info["refine_share_rounds"] == fast.info["refine_share_rounds"]
    assert slow.info["refine_pose_shares"] == fast.info["refine_pose_shares"]
    assert np.allclose(slow.estimate.position, fast.estimate.position, rtol=0, atol=1e-12)


def test_batched_refinement_matches_on_a_lossy_network(small):
    """At 30 % loss the batched path acknowledges and retransmits as the per-message path does: the
    same copies are lost (same per-link draws), and messages, drops, bytes, rounds and the estimate agree."""
    fast, slow = _both_paths(small, EXACT, 1, loss=0.3)
    assert fast.network["drop_reasons"]["loss"] > 0 and fast.levels >= 2
    assert np.array_equal(slow.messages, fast.messages)
    assert np.array_equal(slow.phase_messages, fast.phase_messages)
    assert slow.network == fast.network and slow.rounds == fast.rounds
    assert np.allclose(slow.estimate.position, fast.estimate.position, rtol=0, atol=1e-12)


def test_batched_refinement_matches_in_3d():
    """On a 3D cubic lattice the two paths also count exactly the same messages."""
    ens = generate(EnsembleSpec(shape="box", n=20, lattice="cubic"), np.random.default_rng(2))
    prob = EnsembleProblem.create(ens.dim, ens.n, ens.radius, ens.i, ens.j, ens.z)
    fast, slow = _both_paths(prob, EXACT, 0)
    assert np.array_equal(slow.messages, fast.messages)
    assert slow.network == fast.network and slow.rounds == fast.rounds
    assert np.allclose(slow.estimate.position, fast.estimate.position, rtol=0, atol=1e-12)


def test_batched_refinement_matches_with_two_components(small):
    """Two disconnected components refine side by side (different trees, stopping at different
    iterations) and the batched path still counts exactly what the per-message path counts."""
    problem = small
    n = problem.n
    keep = problem.i < problem.j  # a second copy with every observation reversed: a different component
    two = EnsembleProblem.create(problem.dim, 2 * n, problem.radius,
                                 np.concatenate([problem.i, problem.j[keep] + n, problem.i[keep] + n]),
                                 np.concatenate([problem.j, problem.i[keep] + n, problem.j[keep] + n]),
                                 np.concatenate([problem.z, problem.z[keep][:, ::-1], problem.z[keep]]))
    fast, slow = _both_paths(two, EXACT, 5)
    assert len(np.unique(fast.estimate.component)) == 2 and sum(fast.info["refine_iterations"].values()) > 0
    assert np.array_equal(slow.messages, fast.messages)
    assert slow.network == fast.network and slow.rounds == fast.rounds
    assert slow.info["refine_iterations"] == fast.info["refine_iterations"]
    assert np.allclose(slow.estimate.position, fast.estimate.position, rtol=0, atol=1e-12)


def test_reliable_delivery_without_loss_sends_each_message_once_plus_its_ack(small):
    """With acknowledgements on and no copy lost, nothing is retransmitted: exactly twice the
    lossless messages (each message once, plus one acknowledgement), in every phase."""
    h = HierarchyConfig(leaf_size=6, cut="exact", level_refine=RefineConfig(max_iter=100, gtol=0.01))
    cfg = dict(hierarchy=h, top_gtol=1e-2, check_every=5)
    plain = run_distributed(small, np.random.default_rng(0), DistributedConfig(**cfg))
    acked = run_distributed(small, np.random.default_rng(0), DistributedConfig(**cfg, loss=1e-12))
    assert plain.levels >= 2
    assert acked.network["total"]["dropped"] == 0
    assert np.array_equal(acked.phase_messages, 2 * plain.phase_messages)
    assert np.allclose(acked.estimate.position, plain.estimate.position, rtol=0, atol=1e-12)
