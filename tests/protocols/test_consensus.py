"""Round-synchronous gather: fresh, stale and missing neighbours, and consensus over a lossy network."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import networkx as nx
import numpy as np
import pytest

from decentral.averaging import consensus_step, metropolis_weight
from decentral.errors import ProtocolError
from protocols.consensus import RoundGather, exchange_round
from protocols.messages import BROADCAST, AdmmPrimal, Heartbeat, Message, as_array, register
from protocols.network import Crash, LinkConfig, NetworkConfig, SimulatedNetwork


@register
@dataclass(frozen=True, slots=True, eq=False, kw_only=True)
class Value(Message):
    """Test kind: one float vector."""

    KIND: ClassVar[str] = "test.value"
    x: np.ndarray

    def __post_init__(self) -> None:
        Message.__post_init__(self)
        object.__setattr__(self, "x", as_array(self.x, "x", dtype=np.float64, ndim=1))


def v(sender: str, k: int, x: float = 0.0, receiver: str = BROADCAST) -> Value:
    return Value(sender=sender, receiver=receiver, round=k, x=[x])


def test_all_fresh_when_everything_arrives():
    """A round with every neighbour's message is complete, with no stale or missing neighbour."""
    g = RoundGather("A", ["B", "C"], Value)
    g.receive([v("B", 0), v("C", 0)])
    r = g.close(0)
    assert set(r.fresh) == {"B", "C"} and r.complete and not r.stale and r.missing == () and r.late == ()


def test_missing_senders_are_reported_at_the_deadline():
    """A neighbour never heard from is listed in missing (and late)."""
    g = RoundGather("A", ["B", "C"], Value)
    g.receive([v("B", 0)])
    r = g.close(0)
    assert r.missing == ("C",) and r.late == ("C",) and not r.complete


def test_stale_value_is_reused_with_its_age():
    """A neighbour silent in round 3 is represented by its newest older message, with age = 3 - its round."""
    g = RoundGather("A", ["B"], Value)
    g.receive([v("B", 0, 1.0)])
    g.close(0)
    g.receive([v("B", 1, 2.0)])
    g.close(1)
    g.close(2)
    r = g.close(3)
    assert r.stale["B"].x[0] == 2.0 and r.ages["B"] == 2 and r.missing == () and r.late == ("B",)


def test_late_message_becomes_a_stale_value():
    """A round-1 message arriving after round 1 closed is used as the stale value of round 2."""
    g = RoundGather("A", ["B"], Value)
    g.close(0)
    g.close(1)
    g.receive([v("B", 1, 5.0)])
    r = g.close(2)
    assert r.stale["B"].round == 1 and r.ages["B"] == 1


def test_future_messages_wait_for_their_round():
    """A message for a later round is held and counted fresh when that round closes."""
    g = RoundGather("A", ["B"], Value)
    g.receive([v("B", 2)])
    assert g.close(0).missing == ("B",)
    assert "B" in g.close(2).fresh


def test_duplicates_and_foreign_messages_are_ignored():
    """Duplicates, other kinds, non-neighbours and messages for other receivers are not taken."""
    g = RoundGather("A", ["B"], Value)
    taken = g.receive([
        v("B", 0), v("B", 0), v("Z", 0), v("B", 0, receiver="C"),
        Heartbeat(sender="B", receiver="A", round=0, t=0.0),
    ])
    assert taken == 1 and set(g.close(0).fresh) == {"B"}


def test_accept_filter_applies():
    """Messages refused by the accept filter (e.g. another ADMM window) are not taken."""
    g = RoundGather("A", ["B"], AdmmPrimal, accept=lambda m: m.window == 7)
    g.receive([AdmmPrimal(sender="B", receiver="A", round=0, window=6, blocks={})])
    assert g.close(0).missing == ("B",)


def test_rounds_close_in_order():
    """Closing a round again, or an earlier one, is a ProtocolError."""
    g = RoundGather("A", ["B"], Value)
    g.close(3)
    with pytest.raises(ProtocolError):
        g.close(3)


def _average(loss: float, crashes=(), rounds: int = 150, seed: int = 0):
    graph = nx.cycle_graph(8)
    graph.add_edges_from([(0, 4), (2, 6)])
    names = [f"A{i}" for i in graph]
    x0 = {f"A{i}": float(i) for i in graph}
    network = SimulatedNetwork(
        NetworkConfig(agents=tuple(names), link=LinkConfig(drop=loss, latency=0.01, jitter=0.02, duplicate=0.1),
                      crashes=tuple(crashes)),
        np.random.default_rng(seed),
    )
    nb = {f"A{i}": [f"A{j}" for j in graph[i]] for i in graph}
    w = {a: {b: metropolis_weight(len(nb[a]), len(nb[b])) for b in nb[a]} for a in names}
    gathers = {a: RoundGather(a, nb[a], Value) for a in names}
    x = dict(x0)
    history = []
    for k in range(rounds):
        make = {a: (lambda r, a=a, k=k: v(a, k, x[a], r)) for a in names if not network.is_down(a, k * 0.1)}
        results = exchange_round(network, gathers, make, k, period=0.1, deadline=0.08)
        for a in names:
            if network.is_down(a, k * 0.1):
                continue
            fresh = {b: m.x[0] for b, m in results[a].fresh.items()}
            x[a] = float(consensus_step(np.array(x[a]), fresh, w[a])[()])
        history.append(dict(x))
    return x0, x, history, network


def test_lossless_averaging_reaches_the_mean():
    """Without loss, Metropolis averaging over the gather converges to the exact mean."""
    x0, x, _, _ = _average(0.0)
    assert np.allclose(list(x.values()), np.mean(list(x0.values())), atol=1e-6)


def test_lossy_averaging_still_agrees():
    """With 30 % loss plus duplication the agents still agree (spread < 1e-3) near the initial mean."""
    x0, x, _, _ = _average(0.3, rounds=300)
    vals = np.array(list(x.values()))
    assert np.ptp(vals) < 1e-3
    assert abs(vals.mean() - np.mean(list(x0.values()))) < 0.5


def test_crashed_agent_catches_up():
    """Peers go on while an agent is down; after it returns all agents agree again."""
    _, x, history, network = _average(0.0, crashes=(Crash("A3", 2.0, 6.0),), rounds=200)
    during = history[40]
    assert np.ptp([during[a] for a in during if a != "A3"]) < np.ptp(list(during.values()))
    assert np.ptp(list(x.values())) < 1e-4
    assert network.stats().drop_reasons.get("receiver_down", 0) > 0
