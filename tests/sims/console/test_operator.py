"""Kanovsky's operator loop over the swarm (OperatorSwarm): nothing happens unless commanded, and the
picture -> report -> read chain places robots against the truth."""

from __future__ import annotations

import math

import numpy as np
import pytest

from decentral.errors import InputError
from protocols.messages import OdometryReport
from protocols.network import LinkConfig
from sims.console.operator import OperatorSwarm
from sims.simulation.swarm import SwarmConfig

CFG = SwarmConfig(n_robots=4, dt=0.1, dropout=0.0)
SEED = 8  # R1 and R2 see each other, R1 sees R0, R2 does not (asserted where it matters)


def test_without_commands_nobody_tracks_anybody():
    """Robots only dead-reckon until the operator commands a picture: no tracks, only odometry on the radio."""
    op = OperatorSwarm(CFG, SEED)
    for _ in range(5):
        op.tick()
    assert all(not r.tracks for r in op.sim.robots.values())
    kinds = op.sim.network.stats().per_kind
    assert set(kinds) == {OdometryReport.KIND}


def test_drive_moves_only_the_driven_robot_along_its_heading():
    """Forward moves the driven robot along its heading; the undriven robots stand still."""
    op = OperatorSwarm(CFG, SEED)
    before = op.truth()
    op.drive("R0", "forward")
    op.tick()
    after = op.truth()
    d = after[0, :2] - before[0, :2]
    assert np.linalg.norm(d) == pytest.approx(CFG.max_speed * CFG.dt, rel=1e-6)
    assert d @ np.array([math.cos(before[0, 2]), math.sin(before[0, 2])]) > 0
    assert np.array_equal(after[1:], before[1:])


def test_rotate_in_place_keeps_the_position():
    """Left and right turn the robot without moving its centre."""
    op = OperatorSwarm(CFG, SEED)
    before = op.truth()
    op.drive("R2", "left")
    op.tick()
    after = op.truth()
    assert np.allclose(after[2, :2], before[2, :2]) and after[2, 2] != before[2, 2]


def test_picture_tracks_exactly_the_robots_in_the_view_cone():
    """A picture (no tag drop-outs) gives the robot a track of every robot in its cone, and only those."""
    op = OperatorSwarm(CFG, SEED)
    seen = op.picture("R1")
    op.tick()
    assert seen and set(op.sim.robots["R1"].tracks) == set(seen)
    for target, e in op.estimates_of("R1").items():
        assert e["error"] < 0.1, (target, e["error"])


def test_report_is_held_unread_until_the_robot_reads():
    """A report reaches every robot's inbox but changes no estimate until that robot reads."""
    op = OperatorSwarm(CFG, SEED)
    op.picture("R1")
    op.tick()
    op.report("R1")
    op.tick()
    assert all(op.counters()["unread"][n] > 0 for n in ("R0", "R2", "R3"))
    assert not op.sim.robots["R2"].tracks
    op.read("R2")
    op.tick()
    assert op.counters()["unread"]["R2"] == 0


def test_one_loop_places_a_robot_the_reader_cannot_see():
    """Picture, report and read at one instant: R2 places R0 (out of its view) from R1's report."""
    op = OperatorSwarm(CFG, SEED)
    assert "R0" in op.in_view("R1") and "R2" in op.in_view("R1") and "R1" in op.in_view("R2")
    assert "R0" not in op.in_view("R2")
    op.loop_all()
    op.tick()
    est = op.estimates_of("R2")
    assert est["R0"]["source"] == "peer" and est["R0"]["error"] < 0.3


def test_a_report_read_after_its_subject_moved_is_discarded():
    """A held estimate of a robot that has moved since is stale: discarded and counted, never fused."""
    op = OperatorSwarm(CFG, SEED)
    op.loop_all()
    op.tick()
    op.report("R1")
    op.tick()
    op.drive("R0", "forward")
    for _ in range(3):
        op.tick()
    fused = op.sim.robots["R2"].stats.fused
    op.read("R2")
    op.tick()
    assert op.stale_discarded >= 1 and op.sim.robots["R2"].stats.fused == fused


def test_auto_loop_tracks_more_robots_over_time():
    """With the swarm's own loop every step, robots come to track others."""
    op = OperatorSwarm(SwarmConfig(n_robots=5, arena=3.0, dt=0.2), 3, auto=True)
    for _ in range(25):
        op.tick()
    assert np.sum(op.history[-1].tracked) > 0


def test_link_loss_follows_the_radio():
    """Recent loss per link is 0 on a perfect radio and 1 when every copy is lost."""
    ok = OperatorSwarm(CFG, SEED)
    lost = OperatorSwarm(SwarmConfig(n_robots=4, dt=0.1, link=LinkConfig(drop=1.0)), SEED)
    for _ in range(2):
        ok.tick()
        lost.tick()
    off = ~np.eye(4, dtype=bool)
    assert np.all(ok.link_loss()[off] == 0.0) and np.all(lost.link_loss()[off] == 1.0)


def test_unknown_robot_or_command_is_an_input_error():
    """Commands name a robot and an action the loop knows; anything else is an InputError."""
    op = OperatorSwarm(CFG, SEED)
    with pytest.raises(InputError):
        op.picture("R9")
    with pytest.raises(InputError):
        op.command("R0", "jump")


def test_same_seed_and_commands_same_run():
    """The same seed and command sequence reproduce the same truth and estimates."""
    def run():
        op = OperatorSwarm(CFG, SEED)
        op.drive("R0", "left")
        op.loop_all()
        for _ in range(3):
            op.tick()
        return op.truth(), {k: (v["x"], v["y"]) for k, v in op.estimates_of("R2").items()}
    (t1, e1), (t2, e2) = run(), run()
    assert np.array_equal(t1, t2) and e1 == e2


def test_own_traffic_totals_match_the_radio_books():
    """The per-step message and byte totals kept by the loop equal the radio's own counters."""
    op = OperatorSwarm(SwarmConfig(n_robots=5, arena=3.0, dt=0.2), 4, auto=True)
    for _ in range(6):
        op.tick()
    total = op.sim.network.stats().total
    assert (op.history[-1].messages, op.history[-1].bytes) == (total.sent, total.bytes_sent)


def test_a_moved_robot_reaches_a_readers_estimate_through_a_report():
    """R0 drives about 0.3 m; after R1's picture and report, R2 (which cannot see R0) reads and places
    R0 at its new place, its error falling to under half."""
    op = OperatorSwarm(CFG, SEED)
    op.loop_all()
    op.tick()
    for _ in range(6):
        op.drive("R0", "forward")  # a held key renews the command every step
        op.tick()
    for _ in range(6):
        op.tick()
    assert "R0" not in op.in_view("R2")
    held = op.estimates_of("R2")["R0"]["error"]
    op.picture("R1")
    op.tick()
    op.report("R1")
    op.tick()
    assert op.estimates_of("R2")["R0"]["error"] == pytest.approx(held, abs=0.03)  # unread: nothing changes
    op.read("R2")
    op.tick()
    assert op.estimates_of("R2")["R0"]["error"] < 0.5 * held
