"""A lying member on the simulated network: honest data raise no alarm, the lies the statistics can see are flagged.

Runs ``localize --mode admm``'s runtime (:func:`sims.runners.admm_run.run_admm`) on 5-assembly logs; about a
second of CPU per run, so marked slow. Figures in docs/robustness.md ("A lying member").
"""

from __future__ import annotations

import pytest

from decentral.estimator import EstimatorConfig, estimate_log
from decentral.metrics import estimate_gap
from sims.runners.admm_run import run_admm
from sims.simulation.scenarios import get_scenario, simulate
from tests.synthetic import lying, without


def _log(seed: int, n: int = 5):
    return simulate(get_scenario("multi", n_assemblies=n, steps=8), seed=seed).log


@pytest.mark.slow
@pytest.mark.parametrize("n", [4, 5, 6])
def test_honest_data_exclude_no_one_over_twenty_seeds(n):
    """Seeds 21-40 (not those the thresholds were calibrated on), rings of 4-6: no one excluded or suspected, every
    step centralized."""
    for seed in range(21, 41):
        log = _log(seed, n)
        run = run_admm(log, "A0")
        assert run.stats["excluded"] == [] and run.stats["suspects"] == [], (seed, run.stats["excluded"])
        dp, _, mismatched = estimate_gap(estimate_log(log, EstimatorConfig(window=5)), run.estimate)
        assert mismatched == 0 and dp < 1e-3, (seed, dp, mismatched)


@pytest.mark.slow
@pytest.mark.parametrize("lie", ["layout", "node_ids"])
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_stretched_layout_or_claimed_node_ids_are_flagged_and_no_honest_member_is_excluded(lie, seed):
    """A3 stretches its layout 1.5x or claims A4's node ids: A3 is excluded or among the suspects, and no one else is
    excluded."""
    run = run_admm(lying(_log(seed), "A3", lie), "A0")
    assert "A3" in set(run.stats["excluded"]) | set(run.stats["suspects"]), run.stats
    assert set(run.stats["excluded"]) <= {"A3"}, run.stats["excluded"]


@pytest.mark.slow
@pytest.mark.parametrize("seed", [3, 4])
def test_a_stretched_layout_two_observers_check_is_excluded_and_the_rest_is_centralized_without_it(seed):
    """A3's layout stretched 1.5x (seen by A1 and A2, A2 much the closer): A3 alone is excluded, every step equals the
    centralized estimate without A3 (1 mm)."""
    log = _log(seed)
    run = run_admm(lying(log, "A3", "layout"), "A0")
    assert run.stats["excluded"] == ["A3"], run.stats
    dp, _, mismatched = estimate_gap(estimate_log(without(log, "A3"), EstimatorConfig(window=5)), run.estimate)
    assert mismatched == 0 and dp < 1e-3, (dp, mismatched)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [5, 15])
def test_odometry_scaled_five_times_is_named_and_no_honest_member_is_excluded(seed):
    """A3's odometry scaled 5x on logs where A3 moves 7-10 mm a step: A3 is excluded and no one else."""
    run = run_admm(lying(_log(seed), "A3", "odometry"), "A0")
    assert run.stats["excluded"] == ["A3"], run.stats


@pytest.mark.slow
@pytest.mark.parametrize("seed", [5, 15])
def test_odometry_scaled_five_times_leaves_the_rest_centralized_without_the_liar(seed):
    """With that lie, every step equals the centralized estimate without A3 (1 mm): the first steps, whose windows
    hold too few odometry links to name A3 (68-234 mm off when answered), are answered again once a later window
    excludes it (stats.revised, reason "excluded")."""
    log = _log(seed)
    run = run_admm(lying(log, "A3", "odometry"), "A0")
    dp, _, mismatched = estimate_gap(estimate_log(without(log, "A3"), EstimatorConfig(window=5)), run.estimate)
    assert mismatched == 0 and dp < 1e-3, (dp, mismatched)
    assert {r["reason"] for r in run.stats["revised"]} == {"excluded"}
