"""The ZeroMQ transport over real loopback sockets: delivery, counting, receive-side faults, refusals, processes."""

from __future__ import annotations

import json
import math
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from decentral.errors import InputError, ProtocolError
from protocols.auth import new_private_key, public_key_bytes
from protocols.messages import BROADCAST, Heartbeat
from protocols.network import LinkConfig
from protocols.peers import Peer, peers_json, private_key_json
from protocols.transport import Transport, TransportStats, merge_stats
from protocols.zmq_transport import ZmqTransport, open_loopback

ROOT = Path(__file__).resolve().parents[2]


def hb(a: str, b: str, k: int) -> Heartbeat:
    return Heartbeat(sender=a, receiver=b, round=k, t=0.0)


def collect(transports: dict, n: int, timeout: float = 10.0) -> dict[str, list]:
    """Poll every transport (as wall-clock runtimes would) until ``n`` copies arrived in all or ``timeout``."""
    got: dict[str, list] = {name: [] for name in transports}
    deadline = time.monotonic() + timeout
    while sum(map(len, got.values())) < n and time.monotonic() < deadline:
        for name, t in transports.items():
            t.wait(0.005)
            got[name] += t.poll(name, time.monotonic())
    return got


@pytest.fixture
def trio():
    transports, peers = open_loopback(["A0", "A1", "A2"])
    yield transports
    for t in transports.values():
        t.close()


def test_is_a_transport(trio):
    """The real transport implements the agents' Transport interface."""
    assert isinstance(trio["A0"], Transport) and trio["A0"].agents == ("A0",)
    assert trio["A0"].peers == ("A0", "A1", "A2")


def test_unicast_and_broadcast_arrive_once_in_order(trio):
    """Unicasts reach their receiver and broadcasts every other agent, each once, in send order per link."""
    for k in range(20):
        trio["A0"].send(hb("A0", BROADCAST, k), time.monotonic())
        trio["A1"].send(hb("A1", "A2", k), time.monotonic())
    got = collect(trio, 60)
    assert [d.message.round for d in got["A1"]] == list(range(20))
    assert [d.message for d in got["A2"] if d.sender == "A1"] == [hb("A1", "A2", k) for k in range(20)]
    assert [d.message for d in got["A2"] if d.sender == "A0"] == [hb("A0", BROADCAST, k) for k in range(20)]
    assert got["A0"] == []


def test_merged_counts_balance_and_bytes_include_the_envelope(trio):
    """Merged over processes, sent + duplicated == delivered + dropped + in_flight per link, and bytes are envelope bytes."""
    for k in range(10):
        trio["A0"].send(hb("A0", BROADCAST, k), time.monotonic())
    got = collect(trio, 20)
    s = merge_stats([t.stats() for t in trio.values()])
    assert s.total.sent == s.total.delivered == 20 and s.total.in_flight == 0
    assert all(c.balanced() for table in (s.per_link, s.per_sender, s.per_kind) for c in table.values())
    size = hb("A0", BROADCAST, 0).size_bytes + 98 + 2
    assert s.total.bytes_sent == s.total.bytes_delivered == 20 * size
    assert {d.size_bytes for d in got["A1"]} == {size}
    assert trio["A0"].stats().per_link[("A0", "A1")].in_flight == 10  # the sender's half of the books
    assert trio["A1"].stats().per_link[("A0", "A1")].in_flight == -10  # the receiver's half


def test_sender_must_be_local_and_receiver_known(trio):
    """Sending as another agent raises; a unicast to a name not in the peers file is dropped as unknown_receiver."""
    with pytest.raises(ProtocolError):
        trio["A0"].send(hb("A1", "A2", 0), 0.0)
    trio["A0"].send(hb("A0", "ghost", 0), 0.0)
    assert trio["A0"].stats().drop_reasons == {"unknown_receiver": 1}


def lossy_history(seed: int, n: int = 300, **faults) -> tuple[list, object]:
    """Send ``n`` frames A0 -> A1 with receive-side ``faults``; return A1's (round, duplicate) copies and the merged books."""
    transports, _ = open_loopback(["A0", "A1"], seed=seed, faults=LinkConfig(**faults))
    got = []
    try:
        for k in range(n):
            transports["A0"].send(hb("A0", "A1", k), 0.0)
        deadline = time.monotonic() + 10
        while (s := merge_stats([t.stats() for t in transports.values()])).total.in_flight and time.monotonic() < deadline:
            transports["A1"].wait(0.01)
            got += transports["A1"].poll("A1", math.inf)
    finally:
        for t in transports.values():
            t.close()
    return [(d.message.round, d.duplicate) for d in got], s


def test_receive_side_loss_and_duplication_are_seeded_and_counted():
    """Same seed, same copies lost and duplicated; the counts balance and the loss rate is near the setting."""
    faults = dict(drop=0.3, duplicate=0.2)
    rounds, s = lossy_history(3, **faults)
    assert s.total.balanced() and s.total.in_flight == 0 and s.total.sent == 300
    assert s.drop_reasons == {"loss": s.total.dropped} and 60 <= s.total.dropped <= 120
    assert s.total.duplicated == sum(dup for _, dup in rounds) > 0
    assert s.total.delivered == len(rounds) == 300 - s.total.dropped + s.total.duplicated
    assert rounds == lossy_history(3, **faults)[0] != lossy_history(4, **faults)[0]


def test_injected_delay_holds_copies_until_their_arrival_time():
    """With latency d, a copy read at t is handed out at t + d, not before."""
    transports, _ = open_loopback(["A0", "A1"], seed=0, faults=LinkConfig(latency=5.0))
    try:
        transports["A0"].send(hb("A0", "A1", 0), 0.0)
        a1 = transports["A1"]
        deadline = time.monotonic() + 5
        while a1.next_release("A1") is None and time.monotonic() < deadline:
            a1.wait(0.01)
            assert a1.poll("A1", 100.0) == []
        assert a1.next_release("A1") == 105.0
        assert a1.poll("A1", 104.9) == [] and [d.delivered_at for d in a1.poll("A1", 105.0)] == [105.0]
    finally:
        for t in transports.values():
            t.close()


def test_unsupported_faults_and_missing_rng_are_input_errors():
    """Corruption and bandwidth are not injectable at the receiver; random faults need an rng."""
    key = new_private_key()
    peers = {"A0": Peer("A0", "tcp://127.0.0.1:0", public_key_bytes(key))}
    with pytest.raises(InputError, match="corrupt"):
        ZmqTransport({"A0": key}, peers, rng=np.random.default_rng(0), faults=LinkConfig(corrupt=0.1))
    with pytest.raises(InputError, match="rng"):
        ZmqTransport({"A0": key}, peers, faults=LinkConfig(drop=0.1))


def test_key_must_match_the_peers_file():
    """A local key whose public half differs from the peers file's entry is refused."""
    peers = {"A0": Peer("A0", "tcp://127.0.0.1:0", public_key_bytes(new_private_key()))}
    with pytest.raises(InputError, match="does not match"):
        ZmqTransport({"A0": new_private_key()}, peers)


def test_full_queue_to_an_absent_peer_drops_counted_and_never_blocks():
    """Frames to a peer that never starts fill its queue, then are dropped as queue_full, without blocking."""
    key = new_private_key()
    peers = {"A0": Peer("A0", "tcp://127.0.0.1:0", public_key_bytes(key)),
             "A1": Peer("A1", "tcp://127.0.0.1:9", public_key_bytes(new_private_key()))}
    with ZmqTransport({"A0": key}, peers, hwm=50) as t:
        start = time.monotonic()
        for k in range(500):
            t.send(hb("A0", "A1", k), 0.0)
        assert time.monotonic() - start < 5.0
        s = t.stats()
    assert s.total.sent == 500 and s.drop_reasons["queue_full"] == s.total.dropped >= 400
    assert s.total.in_flight == 500 - s.total.dropped


def test_close_is_prompt_and_idempotent_with_frames_queued():
    """Closing with frames still queued to an absent peer returns at once; a closed transport refuses use."""
    key = new_private_key()
    peers = {"A0": Peer("A0", "tcp://127.0.0.1:0", public_key_bytes(key)),
             "A1": Peer("A1", "tcp://127.0.0.1:9", public_key_bytes(new_private_key()))}
    t = ZmqTransport({"A0": key}, peers)
    for k in range(100):
        t.send(hb("A0", "A1", k), 0.0)
    start = time.monotonic()
    t.close()
    t.close()
    assert time.monotonic() - start < 1.0
    with pytest.raises(ProtocolError):
        t.poll("A0", 0.0)


def test_a_restarted_agent_rejoins_and_its_dead_process_frames_are_refused():
    """A fresh transport for the same agent (same key, new epoch) is heard; a replay of the old process's frame is not."""
    transports, peers = open_loopback(["A0", "A1"])
    a0, a1 = transports["A0"], transports["A1"]
    try:
        a0.send(hb("A0", "A1", 0), 0.0)
        assert len(collect({"A1": a1}, 1)["A1"]) == 1
        address = a0.addresses["A0"]
        key = a0._local["A0"].signer._key  # the same agent's key, as a restarted process reads it from its file
        a0.close()
        with ZmqTransport({"A0": key}, peers) as fresh:
            assert fresh.addresses["A0"] == address
            fresh.send(hb("A0", "A1", 7), 0.0)
            got = collect({"A1": a1}, 1)["A1"]
        assert [d.message.round for d in got] == [7] and a1.stats().rejected == {}
    finally:
        a1.close()


CHILD = textwrap.dedent("""
    import json, sys, time
    from protocols.messages import Heartbeat
    from protocols.peers import load_peers, load_private_key
    from protocols.zmq_transport import ZmqTransport
    name, key = load_private_key(sys.argv[1])
    peers = load_peers(sys.argv[2])
    with ZmqTransport({name: key}, peers, bind={name: "tcp://127.0.0.1:0"}) as net:
        print(net.addresses[name], flush=True)
        echoed, deadline = 0, time.monotonic() + 30
        while echoed < int(sys.argv[3]) and time.monotonic() < deadline:
            net.wait(0.05)
            for d in net.poll(name, time.time()):
                net.send(Heartbeat(sender=name, receiver=d.sender, round=d.message.round, t=0.0), time.time())
                echoed += 1
        sys.stdin.readline()  # the parent has everything: now close
        print(json.dumps(net.stats().as_dict()["total"]), flush=True)
""")


def test_echo_across_processes(tmp_path):
    """A child process loads its key and the peers file, echoes every frame back, and the books of both add up."""
    keys = {"P": new_private_key(), "C": new_private_key()}
    with ZmqTransport({"P": keys["P"]}, {n: Peer(n, "tcp://127.0.0.1:0", public_key_bytes(k)) for n, k in keys.items()},
                      bind={"P": "tcp://127.0.0.1:0"}) as parent:
        table = {"P": Peer("P", parent.addresses["P"], public_key_bytes(keys["P"])),
                 "C": Peer("C", "tcp://127.0.0.1:1", public_key_bytes(keys["C"]))}
        (tmp_path / "peers.json").write_text(json.dumps(peers_json(table)))
        (tmp_path / "C.key.json").write_text(json.dumps(private_key_json("C", keys["C"])))
        child = subprocess.Popen([sys.executable, "-c", CHILD, str(tmp_path / "C.key.json"),
                                  str(tmp_path / "peers.json"), "25"], cwd=ROOT, stdin=subprocess.PIPE,
                                 stdout=subprocess.PIPE, text=True)
        try:
            parent.connect({"C": child.stdout.readline().strip()})
            for k in range(25):
                parent.send(hb("P", "C", k), time.time())
            got = collect({"P": parent}, 25)["P"]
            child.stdin.write("done\n")
            child.stdin.flush()
            child_total = json.loads(child.stdout.readline())
        finally:
            child.kill() if child.poll() is None and child.wait(timeout=10) is None else None
        assert [d.message.round for d in got] == list(range(25)) and {d.sender for d in got} == {"C"}
        mine = parent.stats().total
        assert child_total["sent"] == child_total["delivered"] == mine.sent == mine.delivered == 25
        assert mine.in_flight + child_total["in_flight"] == 0


def test_stats_survive_a_json_round_trip(trio):
    """TransportStats.from_dict(as_dict()) gives back the same books (how a launcher reads its agents' stats)."""
    trio["A0"].send(hb("A0", BROADCAST, 0), 0.0)
    collect(trio, 2)
    for t in trio.values():
        s = t.stats()
        assert TransportStats.from_dict(json.loads(json.dumps(s.as_dict()))) == s


def test_close_with_linger_lets_queued_frames_out():
    """Frames sent just before close(linger) still reach a live peer."""
    transports, _ = open_loopback(["A0", "A1"])
    try:
        for k in range(200):
            transports["A0"].send(hb("A0", "A1", k), 0.0)
        transports["A0"].close(linger=5.0)
        got = collect({"A1": transports["A1"]}, 200)["A1"]
        assert [d.message.round for d in got] == list(range(200))
    finally:
        transports["A1"].close()
