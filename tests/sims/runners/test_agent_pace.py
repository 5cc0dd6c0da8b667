"""The process runtime's pace: a process kept off the CPU still ends its run on time, and says it fell behind."""

from __future__ import annotations

import numpy as np

from protocols.network import LinkConfig, NetworkConfig, SimulatedNetwork
from sims.runners.agent_run import Pace, process_agent_config, run_agent
from sims.runners.parts import split_log
from sims.runners.run_status import cpu_hint
from sims.simulation.scenarios import get_scenario, simulate


class _SlowClock:
    """Wall time that moves ``cost`` seconds at every reading (each half round costs more than a half period);
    waiting moves it too. Raises after ``limit`` readings: a runtime that never ends fails the test."""

    def __init__(self, start: float, cost: float, limit: int = 200_000):
        self.t, self.cost, self.limit, self.reads = start, cost, limit, 0

    def __call__(self) -> float:
        self.reads += 1
        assert self.reads < self.limit, "the agent ran past its end"
        self.t += self.cost
        return self.t

    def wait(self, seconds: float) -> None:
        self.t += max(0.0, seconds)


def _run(cost: float):
    log = simulate(get_scenario("multi", n_assemblies=3, steps=4), seed=2).log
    name = log.assemblies[0]
    part = split_log(log)[name]
    net = SimulatedNetwork(NetworkConfig(agents=tuple(log.assemblies), link=LinkConfig(), round_period=0.025),
                           np.random.default_rng(0))
    pace = Pace(start=1000.0, rate=1.0, round_period=0.025, linger=0.5)
    clock = _SlowClock(999.9, cost)
    config = process_agent_config(part, name, name, 5, pace.rate, pace.round_period)
    return part, run_agent(part, name, net, config, pace, clock=clock, wait=clock.wait)


def test_a_process_always_behind_ends_its_run_and_reports_the_lag():
    """Every clock reading costs 30 ms while half rounds are 12.5 ms apart: the agent still stops after its last step
    (instead of running half rounds back to back until killed), counts the times it jumped ahead, and its records say
    how late it ran its half rounds (more than a round at p90), which the warning turns into "short of CPU"."""
    part, run = _run(0.03)
    assert len(run.steps) == len(part.steps)
    assert run.stats["lagged"] >= 1
    assert all(r["behind_ms"][1] > 25.0 for r in run.steps if r["behind_ms"])
    assert run.stats["behind_ms"][1] > 25.0
    assert "short of CPU" in cpu_hint(run.stats["behind_ms"], run.stats["round_period"])
    assert all(r["cpu_ms"] >= 0.0 for r in run.steps) and run.stats["cpu_ms"]["total"] > 0.0


def test_a_process_on_time_reports_its_rounds_on_time_and_no_cpu_hint():
    """A clock reading costs 0.1 ms: the half rounds run within a few ms of their due time, no hint."""
    _, run = _run(0.0001)
    assert run.stats["lagged"] == 0
    assert run.stats["behind_ms"][1] < 5.0
    assert cpu_hint(run.stats["behind_ms"], run.stats["round_period"]) is None
