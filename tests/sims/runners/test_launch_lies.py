"""A lying member as real processes: a layout stretched 1.5x or odometry scaled 5x in its own part of the log is named,
and the rest is the centralized estimate without it.

``launch`` on an 8-step, 5-assembly log at the attack reports' pace (one second of wall time per step),
so marked slow. The simulated-runtime versions are in tests/sims/runners/test_lies_simulated.py.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from decentral.metrics import estimate_gap
from decentral.observations import Estimate
from sims.runners.launch import LaunchConfig, launch
from sims.simulation.scenarios import get_scenario, simulate

PACE = dict(rate=0.2, round_period=0.05, transport="zmq")


def _stretched(parts: dict, liar: str) -> dict:
    """The parts with ``liar``'s own configuration stretched 1.5x about its root (only its part: what it announces)."""
    part = parts[liar]
    steps = [dataclasses.replace(s, config={**s.config, liar: {i: 1.5 * np.asarray(c, float)
                                                               for i, c in s.config[liar].items()}})
             for s in part.steps]
    return {**parts, liar: dataclasses.replace(part, steps=tuple(steps))}


def _converged_steps_are(central, est) -> None:
    """At least half of ``est``'s steps converged, and each of them places what ``central`` places, where it places
    it (1 mm, 0.05 deg)."""
    converged = [k for k, ok in enumerate(est.stats["converged_per_step"]) if ok]
    assert len(converged) >= len(est.steps) // 2, est.stats["status_counts"]
    only = lambda e: Estimate(e.reference, tuple(e.steps[k] for k in converged), e.stats)  # noqa: E731
    dp, dth, mismatched = estimate_gap(only(central), only(est))
    assert mismatched == 0 and dp < 1e-3 and dth < np.radians(0.05), (dp, np.degrees(dth), mismatched)


@pytest.mark.slow
def test_a_stretched_layout_two_observers_check_is_named_and_never_placed(tmp_path, monkeypatch):
    """A3 announces its layout stretched 1.5x (seed 3: seen by A2 and A1): the reference names A3 in `excluded`, no
    one else, and never places A3."""
    import sims.runners.launch as launch_module

    sim = simulate(get_scenario("multi", n_assemblies=5, steps=8), seed=3)
    real_split = launch_module.split_log
    monkeypatch.setattr(launch_module, "split_log", lambda log: _stretched(real_split(log), "A3"))
    est = launch(sim.log, LaunchConfig(**PACE), workdir=tmp_path).estimate
    assert est.stats["excluded"] == ["A3"], est.stats.get("suspects")
    assert not any("A3" in step.poses for step in est.steps)


@pytest.mark.slow
def test_with_the_liar_excluded_every_converged_step_is_the_centralized_estimate_without_it(tmp_path, monkeypatch):
    """The same lie: every step the reference reports converged equals the centralized estimate of the log without
    A3's data (1 mm, 0.05 deg), and at least half of the steps converge."""
    import sims.runners.launch as launch_module
    from decentral.estimator import EstimatorConfig, estimate_log
    from tests.synthetic import without

    sim = simulate(get_scenario("multi", n_assemblies=5, steps=8), seed=3)
    real_split = launch_module.split_log
    monkeypatch.setattr(launch_module, "split_log", lambda log: _stretched(real_split(log), "A3"))
    est = launch(sim.log, LaunchConfig(**PACE), workdir=tmp_path).estimate
    central = estimate_log(without(sim.log, "A3"), EstimatorConfig(window=5))
    _converged_steps_are(central, est)


@pytest.mark.slow
def test_odometry_scaled_five_times_is_named_and_the_rest_is_the_centralized_estimate_without_it(tmp_path,
                                                                                               monkeypatch):
    """A3's own part has its odometry scaled 5x (seed 5: A3 moves 7-10 mm a step): the reference names A3 alone, and
    every step it reports converged, the first ones answered again once a later window named A3, equals the
    centralized estimate without A3 (1 mm, 0.05 deg)."""
    import sims.runners.launch as launch_module
    from decentral.estimator import EstimatorConfig, estimate_log
    from tests.synthetic import lying, without

    sim = simulate(get_scenario("multi", n_assemblies=5, steps=8), seed=5)
    real_split = launch_module.split_log
    monkeypatch.setattr(launch_module, "split_log",
                        lambda log: {**(parts := real_split(log)), "A3": lying(parts["A3"], "A3", "odometry")})
    est = launch(sim.log, LaunchConfig(**PACE), workdir=tmp_path).estimate
    assert est.stats["excluded"] == ["A3"], (est.stats["excluded"], est.stats["suspects"])
    central = estimate_log(without(sim.log, "A3"), EstimatorConfig(window=5))
    _converged_steps_are(central, est)
