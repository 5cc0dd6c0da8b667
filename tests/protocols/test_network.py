"""The simulated lossy network: determinism, loss statistics, partitions, crashes, bandwidth, counters."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from decentral.errors import InputError, ProtocolError
from protocols.messages import BROADCAST, Heartbeat
from protocols.network import Crash, LinkConfig, NetworkConfig, Partition, SimulatedNetwork
from protocols.transport import Transport

AGENTS = ("A0", "A1", "A2", "A3")


def net(seed: int = 0, **kw) -> SimulatedNetwork:
    link = kw.pop("link", LinkConfig(latency=0.01))
    agents = kw.pop("agents", AGENTS)
    return SimulatedNetwork(NetworkConfig(agents=agents, link=link, **kw), np.random.default_rng(seed))


def hb(a: str, b: str, k: int, t: float = 0.0) -> Heartbeat:
    return Heartbeat(sender=a, receiver=b, round=k, t=t)


def run(network: SimulatedNetwork, n_rounds: int, pairs=None) -> list[tuple]:
    """Send one heartbeat per pair per round; return (receiver, sender, round, arrival, dup) tuples."""
    pairs = pairs or [(a, b) for a in network.agents for b in network.agents if a != b]
    got = []
    for k in range(n_rounds):
        t = network.time_of_round(k)
        for a, b in pairs:
            network.send(hb(a, b, k, t), t)
        for agent in network.agents:
            got += [(agent, d.sender, d.message.round, d.delivered_at, d.duplicate)
                    for d in network.poll(agent, t + network.config.round_period)]
    for agent in network.agents:
        got += [(agent, d.sender, d.message.round, d.delivered_at, d.duplicate) for d in network.poll(agent, math.inf)]
    return got


LOSSY = LinkConfig(drop=0.3, latency=0.02, jitter=0.05, duplicate=0.1, corrupt=0.02)


def test_same_seed_same_history():
    """Two networks built from the same seed deliver exactly the same copies at the same times."""
    assert run(net(7, link=LOSSY), 30) == run(net(7, link=LOSSY), 30)


def test_different_seed_different_history():
    """Different seeds give different loss patterns."""
    assert run(net(7, link=LOSSY), 30) != run(net(8, link=LOSSY), 30)


def test_adding_an_agent_keeps_other_links_patterns():
    """A link's drop pattern does not change when another agent joins the network."""
    pairs = [("A0", "A1"), ("A1", "A0")]
    small = run(net(3, link=LOSSY, agents=("A0", "A1")), 50, pairs)
    big_net = net(3, link=LOSSY, agents=("A0", "A1", "A2", "X"))
    big = run(big_net, 50, pairs + [("A2", "A0"), ("X", "A1"), ("A1", "X")])
    keep = [g for g in big if g[1] in ("A0", "A1") and g[0] in ("A0", "A1")]
    assert keep == small


@pytest.mark.parametrize("p", [0.1, 0.5])
def test_loss_rate_matches_configuration(p):
    """The fraction of copies lost agrees with the drop probability (two-sided binomial test, alpha 1e-4)."""
    network = net(11, link=LinkConfig(drop=p))
    n = 0
    for k in range(500):
        for a in AGENTS:
            network.send(hb(a, BROADCAST, k), float(k))
            n += len(AGENTS) - 1
    lost = network.stats().drop_reasons.get("loss", 0)
    assert network.stats().total.sent == n
    assert stats.binomtest(lost, n, p).pvalue > 1e-4


def test_per_datagram_loss_loses_large_frames_more_often_as_the_udp_transport_would():
    """With ``mtu``, ``drop`` is the loss of each datagram: a small message is lost with ``drop``, an 18 KB
    one as often as its datagrams cannot be put back together with their parity
    (``frame_arrival``; 99.9 % binomial interval); without ``mtu`` both are lost with ``drop``."""
    from protocols.baselines.flood import RawStep
    from protocols.datagrams import frame_arrival

    def lost_share(link, n_ids, copies=3000):
        network = net(3, link=link, agents=("A0", "A1"))
        big = RawStep(sender="A0", receiver="A1", round=0, t=0.0, ids=np.arange(n_ids), uvr=np.zeros((n_ids, 3)),
                      odometry=np.zeros(0))
        for k in range(copies):
            network.send(big, 0.001 * k)
        return network.stats().drop_reasons.get("loss", 0) / copies, big.size_bytes

    for link in (LinkConfig(drop=0.1, mtu=1200), LinkConfig(drop=0.1)):
        for n_ids in (5, 560):
            share, size = lost_share(link, n_ids)
            p = 1 - frame_arrival(size, 0.1, 1200) if link.mtu else 0.1
            lo, hi = stats.binomtest(int(round(share * 3000)), 3000, p).proportion_ci(0.999)
            assert lo <= p <= hi or abs(share - p) < 0.01, (link, n_ids, share, p)
    assert lost_share(LinkConfig(drop=0.1, mtu=1200), 560)[0] > 0.25  # an 18 KB frame: about 0.32
    with pytest.raises(InputError):
        LinkConfig(mtu=20)


def test_duplication_rate_matches_configuration():
    """The fraction of delivered copies that are duplicates agrees with the duplicate probability."""
    network = net(5, link=LinkConfig(duplicate=0.2))
    for k in range(1000):
        network.send(hb("A0", "A1", k), float(k))
    got = network.poll("A1", math.inf)
    dups = sum(d.duplicate for d in got)
    assert stats.binomtest(dups, 1000, 0.2).pvalue > 1e-4
    assert len(got) == 1000 + dups


def test_jitter_reorders_and_keeps_latency_bounds():
    """With jitter larger than the send spacing arrivals come out of send order, within [lat, lat+jit]."""
    network = net(2, link=LinkConfig(latency=0.1, jitter=0.5))
    for k in range(50):
        network.send(hb("A0", "A1", k, 0.01 * k), 0.01 * k)
    got = network.poll("A1", math.inf)
    order = [d.message.round for d in got]
    assert sorted(order) == list(range(50)) and order != list(range(50))
    assert all(0.1 - 1e-12 <= d.latency <= 0.6 + 1e-12 for d in got)
    assert [d.delivered_at for d in got] == sorted(d.delivered_at for d in got)


def test_nothing_arrives_before_its_time():
    """poll(now) returns only copies whose arrival time is <= now."""
    network = net(0, link=LinkConfig(latency=0.3))
    network.send(hb("A0", "A1", 0), 0.0)
    assert network.poll("A1", 0.29) == []
    assert len(network.poll("A1", 0.3)) == 1


def test_partition_blocks_exactly_in_its_window():
    """Across a partition, copies sent in [t0, t1) are dropped and all others arrive."""
    part = Partition(t0=2.0, t1=5.0, groups=(frozenset({"A0", "A1"}),))
    network = net(0, partitions=(part,))
    for k in range(8):
        network.send(hb("A0", "A2", k), float(k))  # crosses the cut
        network.send(hb("A0", "A1", k), float(k))  # same side
        network.send(hb("A2", "A3", k), float(k))  # both in the rest group
    rounds = lambda agent, sender: [d.message.round for d in network.poll(agent, math.inf) if d.sender == sender]
    assert rounds("A2", "A0") == [0, 1, 5, 6, 7]
    assert rounds("A1", "A0") == list(range(8))
    assert rounds("A3", "A2") == list(range(8))
    assert network.stats().drop_reasons == {"partition": 3}


def test_crashed_agent_receives_nothing_while_down_and_resumes():
    """A crashed agent gets no copy arriving in its down interval, and gets traffic again after."""
    network = net(0, link=LinkConfig(latency=0.05), crashes=(Crash("A1", 1.0, 3.0),))
    for k in range(6):
        network.send(hb("A0", "A1", k), float(k))
    got = network.poll("A1", math.inf)
    assert [d.message.round for d in got] == [0, 3, 4, 5]
    assert network.stats().drop_reasons == {"receiver_down": 2}


def test_crashed_agent_sends_nothing_while_down():
    """Copies a crashed agent tries to send during its down interval never arrive."""
    network = net(0, crashes=(Crash("A1", 1.0, 3.0),))
    for k in range(5):
        network.send(hb("A1", "A0", k), float(k))
    assert [d.message.round for d in network.poll("A0", math.inf)] == [0, 3, 4]
    assert network.stats().per_sender["A1"].dropped == 2
    assert network.stats().drop_reasons == {"sender_down": 2}


def test_bandwidth_cap_queues_copies():
    """Under a cap of W bytes/s, back-to-back copies of s bytes arrive s/W apart."""
    size = hb("A0", "A1", 0).size_bytes
    network = net(0, link=LinkConfig(latency=0.01, bandwidth=1000.0))
    for k in range(5):
        network.send(hb("A0", "A1", k), 0.0)
    arrivals = [d.delivered_at for d in network.poll("A1", math.inf)]
    expected = [0.01 + (k + 1) * size / 1000.0 for k in range(5)]
    assert np.allclose(arrivals, expected)


def test_bandwidth_is_per_link():
    """A busy link does not delay another link."""
    network = net(0, link=LinkConfig(latency=0.0, bandwidth=100.0))
    for k in range(5):
        network.send(hb("A0", "A1", k), 0.0)
    network.send(hb("A2", "A3", 0), 0.0)
    size = hb("A2", "A3", 0).size_bytes
    assert np.isclose(network.poll("A3", math.inf)[0].delivered_at, size / 100.0)


def test_counters_add_up():
    """For the total and every sender, receiver, link and kind: sent + duplicated = delivered + dropped + in flight."""
    network = net(9, link=LOSSY, crashes=(Crash("A3", 1.0, 2.0),),
                  partitions=(Partition(0.5, 1.5, (frozenset({"A0"}),)),))
    run(network, 20)
    for k in range(3):  # leave some in flight
        network.send(hb("A0", BROADCAST, 100 + k), 100.0)
    s = network.stats()
    rows = [s.total, *s.per_sender.values(), *s.per_receiver.values(), *s.per_link.values(), *s.per_kind.values()]
    assert all(c.balanced() for c in rows)
    assert s.total.in_flight > 0
    assert s.total.dropped == sum(s.drop_reasons.values())
    assert sum(c.sent for c in s.per_link.values()) == s.total.sent
    assert s.total.bytes_sent == sum(c.bytes_sent for c in s.per_sender.values())
    assert set(s.drop_reasons) >= {"loss", "partition", "receiver_down", "corrupt"}


def test_corrupted_copies_never_reach_the_agent():
    """With corruption on, every delivered message decodes to exactly what was sent."""
    network = net(4, link=LinkConfig(corrupt=0.5))
    sent = [hb("A0", "A1", k, float(k)) for k in range(200)]
    for m in sent:
        network.send(m, 0.0)
    got = network.poll("A1", math.inf)
    assert 0 < len(got) < 200
    assert all(d.message == sent[d.message.round] for d in got)
    assert network.stats().drop_reasons["corrupt"] == 200 - len(got)
    assert network.stats().rejected == {"corrupt": 200 - len(got)}  # refused by the receiver, by reason


def test_broadcast_reaches_every_other_agent():
    """A broadcast is one copy per other agent, none to the sender."""
    network = net(0)
    network.send(hb("A0", BROADCAST, 0), 0.0)
    inbox = network.deliver(1.0)
    assert [len(inbox[a]) for a in AGENTS] == [0, 1, 1, 1]
    assert network.stats().per_sender["A0"].sent == 3


def test_stats_snapshot_is_frozen():
    """A stats snapshot does not change when traffic continues."""
    network = net(0)
    network.send(hb("A0", "A1", 0), 0.0)
    before = network.stats()
    network.send(hb("A0", "A1", 1), 0.0)
    assert before.total.sent == 1 and network.stats().total.sent == 2
    with pytest.raises(TypeError):
        before.per_sender["A9"] = before.total


def test_unknown_sender_is_a_protocol_error():
    """Sending from an agent that is not attached raises ProtocolError."""
    with pytest.raises(ProtocolError):
        net(0).send(hb("ZZ", "A0", 0), 0.0)


def test_unknown_receiver_is_counted_as_dropped():
    """A copy to an agent that is not attached is dropped, reason unknown_receiver."""
    network = net(0)
    network.send(hb("A0", "ZZ", 0), 0.0)
    assert network.stats().drop_reasons == {"unknown_receiver": 1}


@pytest.mark.parametrize(
    "make",
    [
        lambda: LinkConfig(drop=1.5),
        lambda: LinkConfig(latency=-1.0),
        lambda: LinkConfig(bandwidth=0.0),
        lambda: Partition(3.0, 1.0, ()),
        lambda: Partition(0.0, 1.0, (frozenset({"a"}), frozenset({"a", "b"}))),
        lambda: NetworkConfig(agents=("a", "a")),
        lambda: NetworkConfig(agents=("a", "b"), links={("a", "c"): LinkConfig()}),
    ],
)
def test_bad_configuration_is_input_error(make):
    """Invalid network configurations raise InputError naming the field."""
    with pytest.raises(InputError):
        make()


def test_simulated_network_is_a_transport():
    """SimulatedNetwork implements the Transport interface."""
    assert isinstance(net(0), Transport)
