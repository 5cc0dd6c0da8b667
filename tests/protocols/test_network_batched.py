"""The batched path of the simulated network (send_many / poll_many) against the per-message path."""

from __future__ import annotations

import math

import numpy as np
import pytest

from decentral.errors import ProtocolError
from protocols.messages import Heartbeat
from protocols.network import Crash, LinkConfig, NetworkConfig, Partition, SimulatedNetwork

AGENTS = ("A0", "A1", "A2", "A3", "A4")
LOSSY = LinkConfig(drop=0.3, latency=0.02, jitter=0.05, duplicate=0.1, corrupt=0.05)


def config(**kw) -> NetworkConfig:
    kw.setdefault("link", LOSSY)
    return NetworkConfig(agents=AGENTS, **kw)


def traffic(seed: int, n_rounds: int):
    """A fixed random list of (round, sender index, receiver index) copies, several per link per round."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n_rounds):
        m = 12
        s = rng.integers(0, len(AGENTS), m)
        r = (s + rng.integers(1, len(AGENTS), m)) % len(AGENTS)
        out.append((k, s, r))
    return out


def per_message(cfg: NetworkConfig, plan, period: float = 0.1):
    net = SimulatedNetwork(cfg, np.random.default_rng(5))
    got = []
    for k, s, r in plan:
        t = k * period
        for a, b in zip(s.tolist(), r.tolist()):
            net.send(Heartbeat(sender=AGENTS[a], receiver=AGENTS[b], round=k, t=t), t)
        for agent in AGENTS:
            got += [(d.receiver, d.sender, d.message.round, d.delivered_at, d.duplicate) for d in net.poll(agent, t + period)]
    for agent in AGENTS:
        got += [(d.receiver, d.sender, d.message.round, d.delivered_at, d.duplicate) for d in net.poll(agent, math.inf)]
    return sorted(got), net.stats().as_dict()


def batched(cfg: NetworkConfig, plan, period: float = 0.1):
    net = SimulatedNetwork(cfg, np.random.default_rng(5))
    size = Heartbeat(sender="A0", receiver="A1", round=0, t=0.0).size_bytes
    rounds = {}
    got = []

    def take(batch):
        for b, i, s, r, at, dup in zip(batch.batch.tolist(), batch.index.tolist(), batch.sender.tolist(),
                                       batch.receiver.tolist(), batch.arrival.tolist(), batch.duplicate.tolist()):
            got.append((AGENTS[r], AGENTS[s], rounds[b], at, dup))

    for k, s, r in plan:
        t = k * period
        rounds[net.send_many("heartbeat", s, r, size, t)] = k
        take(net.poll_many(t + period))
    take(net.poll_many(math.inf))
    return sorted(got), net.stats().as_dict()


def test_batched_path_reproduces_the_per_message_path():
    """Same seed, same copies: loss, corruption, duplicates, jitter and every counter agree exactly."""
    plan = traffic(1, 40)
    a, sa = per_message(config(), plan)
    b, sb = batched(config(), plan)
    assert sa["drop_reasons"]["loss"] > 0 and sa["drop_reasons"]["corrupt"] > 0 and sa["total"]["duplicated"] > 0
    assert a == b
    assert sa == sb


def test_batched_path_applies_per_datagram_loss_as_the_per_message_path():
    """With an ``mtu`` on the links (per-datagram loss), both paths still lose the same copies."""
    plan = traffic(2, 30)
    cfg = config(link=LinkConfig(drop=0.3, latency=0.02, jitter=0.05, mtu=200),
                 links={("A1", "A2"): LinkConfig(drop=0.2, mtu=100)})
    a, sa = per_message(cfg, plan)
    b, sb = batched(cfg, plan)
    assert sa["drop_reasons"]["loss"] > 0 and a == b and sa == sb


def test_batched_path_honours_partitions_crashes_and_bandwidth():
    """Refusals (partition, sender down), receiver-down drops, overrides and bandwidth queues match."""
    cfg = config(
        links={("A0", "A1"): LinkConfig(drop=0.5, bandwidth=2000.0), ("A2", "A3"): LinkConfig(latency=0.3)},
        partitions=(Partition(0.5, 1.5, (frozenset({"A0", "A1"}),)),),
        crashes=(Crash("A4", 1.0, 2.0),),
    )
    plan = traffic(2, 40)
    a, sa = per_message(cfg, plan)
    b, sb = batched(cfg, plan)
    for reason in ("partition", "sender_down", "receiver_down", "loss"):
        assert sa["drop_reasons"].get(reason, 0) > 0, reason
    assert a == b
    assert sa == sb


def test_batched_counts_balance():
    """For every key, sent + duplicated == delivered + dropped + in_flight, also mid-flight."""
    net = SimulatedNetwork(config(), np.random.default_rng(0))
    net.send_many("x", [0, 1, 2, 3], [1, 2, 3, 4], 100, 0.0)
    net.poll_many(0.04)
    st = net.stats()
    assert st.total.sent == 4
    assert st.total.balanced()
    assert all(c.balanced() for c in st.per_link.values())
    assert sum(net.pending(a) for a in AGENTS) == st.total.in_flight


def test_batched_send_refuses_time_going_back():
    """A batched send earlier than an earlier send is a protocol error, on both paths."""
    net = SimulatedNetwork(config(), np.random.default_rng(0))
    net.send_many("x", [0], [1], 10, 1.0)
    with pytest.raises(ProtocolError):
        net.send_many("x", [0], [1], 10, 0.5)
    with pytest.raises(ProtocolError):
        net.send(Heartbeat(sender="A0", receiver="A1", round=0, t=0.0), 0.5)


def test_batched_send_refuses_unknown_agents():
    """An agent index outside the network is a protocol error, not a silent drop."""
    net = SimulatedNetwork(config(), np.random.default_rng(0))
    with pytest.raises(ProtocolError):
        net.send_many("x", [0], [len(AGENTS)], 10, 0.0)
