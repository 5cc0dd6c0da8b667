"""Agents told different start times: the skew is found from the peers' round numbers, reported, and followed."""

from __future__ import annotations

import pytest

from sims.runners.start_clock import StartClock


def _frames(clock: StartClock, peer: str, peer_start: float, start: float, times, stall: float = 0.0) -> None:
    """Frames ``peer`` sends at ``times`` (its rounds from ``peer_start``; every other one taken ``stall`` s before
    the send, a sender kept off the CPU between its round and the send)."""
    for i, s in enumerate(times):
        clock.heard(peer, int((s - stall * (i % 2) - peer_start) // clock.round_period), s, start - clock.moved)


def test_frames_read_late_do_not_look_like_a_peer_ahead():
    """Peers told the same start, some of whose frames leave 0.4 s after their round was taken: no skew, nothing
    followed. (How late a frame is read does not enter: the bound uses the sender's send time.)"""
    clock = StartClock(round_period=0.025)
    for peer, stall in (("A1", 0.0), ("A2", 0.4)):
        _frames(clock, peer, 100.0, 100.0, [100.0 + 0.025 * i + 0.01 for i in range(200)], stall=stall)
    assert clock.follow() == 0.0 and clock.skewed() == {}


def test_agents_told_the_same_start_see_no_skew_and_move_nothing():
    """Peers told the same start: every offset is within the tolerance, none is skewed and the start stays."""
    clock = StartClock(round_period=0.05)
    for peer in ("A1", "A2"):
        _frames(clock, peer, 100.0, 100.0, [100.0 + 0.05 * i + 0.01 for i in range(60)])
    assert clock.follow() == 0.0 and clock.skewed() == {}
    assert all(abs(d) < clock.tolerance for d in clock.offsets().values())


def test_a_peer_that_started_a_second_earlier_is_reported_and_followed():
    """A peer started 1 s before this agent: its offset reads +1 s (within a round), and the start moves 1 s earlier."""
    clock = StartClock(round_period=0.05)
    _frames(clock, "A0", 99.0, 100.0, [100.0 + 0.05 * i + 0.01 for i in range(40)])
    moved = clock.follow()
    assert abs(moved - 1.0) <= 0.05 + 0.004 and moved <= 1.0  # a lower bound: never past the peer's start
    assert set(clock.skewed()) == {"A0"} and abs(clock.skewed()["A0"] - 1.0) < 0.06


def test_a_peer_that_started_later_is_reported_but_not_followed():
    """A peer started 1 s after this agent: reported at -1 s, and this agent's start does not move."""
    clock = StartClock(round_period=0.05)
    _frames(clock, "A2", 101.0, 100.0, [101.0 + 0.05 * i + 0.01 for i in range(40)])
    assert clock.follow() == 0.0 and abs(clock.offsets()["A2"] + 1.0) < 0.06


def test_a_start_beyond_the_follow_limit_is_reported_and_not_followed():
    """A peer claiming a start 60 s earlier is reported as skewed but not followed."""
    clock = StartClock(round_period=0.05)
    _frames(clock, "A0", 40.0, 100.0, [100.0 + 0.05 * i for i in range(40)])
    assert clock.follow() == 0.0 and "A0" in clock.skewed()


@pytest.mark.slow
@pytest.mark.parametrize("offset", [1.0, -1.0])
def test_a_one_second_start_skew_is_reported_and_the_run_stays_exact(tmp_path, offset):
    """A2 is told a start 1 s later (or earlier) than the others: it (or they) report the skew and follow the earliest
    start, and every converged step equals the centralized estimate (1 mm): at least 8 of 10 converge, or 5 when A2,
    told the earlier start, found itself late and skipped step 0 (its data of step 0 then never exist, and the
    windows holding that step stay provisional)."""
    from decentral.estimator import EstimatorConfig, estimate_log
    from sims.runners.launch import LaunchConfig, launch
    from sims.simulation.scenarios import get_scenario, simulate
    from tests.sims.runners.test_launch_attacks import PACE, _gaps_on_converged

    sim = simulate(get_scenario("multi", n_assemblies=5, steps=10), seed=1)
    central = estimate_log(sim.log, EstimatorConfig(window=5))
    est = launch(sim.log, LaunchConfig(**PACE, start_offsets=(("A2", offset),)), workdir=tmp_path).estimate
    clock = est.stats["clock"]
    late = ["A2"] if offset > 0 else [a for a in clock if a != "A2"]
    for name in late:
        assert clock[name]["skewed"] and abs(clock[name]["moved"] - 1.0) < 0.2, clock
    assert sum(est.stats["converged_per_step"]) >= (8 if offset > 0 else 5), est.stats["converged_per_step"]
    gaps = _gaps_on_converged(central, est)
    assert max(gaps) < 1e-3, gaps
    if offset > 0:
        assert "start times disagree" in (tmp_path / "A2.0.err").read_text()
