"""The ZeroMQ transport over real loopback sockets: delivery, counting, receive-side faults, refusals, processes."""

from __future__ import annotations

import json
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
from protocols.network import LinkConfig, NetworkConfig, SimulatedNetwork
from protocols.peers import Peer, peers_json, private_key_json
from protocols.transport import Transport, TransportStats, merge_stats
from protocols.zmq_transport import ZmqTransport, open_loopback

ROOT = Path(__file__).resolve().parents[2]


def hb(a: str, b: str, k: int) -> Heartbeat:
    return Heartbeat(sender=a, receiver=b, round=k, t=0.0)


def stop(proc: subprocess.Popen) -> None:
    """Let a child process finish for up to 10 s, then kill it: no test leaves a process behind."""
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def collect(transports: dict, n: int | None = None, timeout: float = 10.0) -> dict[str, list]:
    """Poll every transport (as wall-clock runtimes would) until ``n`` copies arrived in all (``None``: until
    the merged books have nothing in flight) or ``timeout``."""
    got: dict[str, list] = {name: [] for name in transports}
    deadline = time.monotonic() + timeout

    def done() -> bool:
        if n is None:
            return merge_stats([t.stats() for t in transports.values()]).total.in_flight == 0
        return sum(map(len, got.values())) >= n

    while not done() and time.monotonic() < deadline:
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
    """Merged over processes, sent + duplicated == delivered + dropped + in_flight per link, and bytes are
    envelope bytes."""
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
    """Send ``n`` frames A0 -> A1 with receive-side ``faults``; return A1's (round, duplicate) copies and
    the merged books."""
    transports, _ = open_loopback(["A0", "A1"], seed=seed, faults=LinkConfig(**faults))
    try:
        for k in range(n):
            transports["A0"].send(hb("A0", "A1", k), 0.0)
        got = collect(transports)["A1"]
        s = merge_stats([t.stats() for t in transports.values()])
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
    """A fresh process for the same agent (same key and address, new epoch) is heard at once, nothing refused
    (the gate tests show its old process's frames are then replays)."""
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
        (tmp_path / "C.key.json").chmod(0o600)
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
            stop(child)
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


def test_counts_match_the_simulated_network_for_the_same_traffic(trio):
    """The same sends give the same per-link and per-kind message counts as the simulated network; bytes
    differ by exactly the envelope (98 bytes + the sender's name) per copy."""
    sim = SimulatedNetwork(NetworkConfig(agents=("A0", "A1", "A2")), np.random.default_rng(0))
    traffic = [hb("A0", BROADCAST, 0), hb("A1", "A2", 1), hb("A2", BROADCAST, 2), hb("A2", "A0", 3)]
    for m in traffic:
        sim.send(m, 0.0)
        trio[m.sender].send(m, 0.0)
    sim.deliver(1.0)
    collect(trio, 6)
    real, ref = merge_stats([t.stats() for t in trio.values()]), sim.stats()
    assert set(real.per_link) == set(ref.per_link)
    for link, c in ref.per_link.items():
        r = real.per_link[link]
        assert (r.sent, r.delivered, r.dropped, r.in_flight) == (c.sent, c.delivered, c.dropped, c.in_flight)
        assert r.bytes_sent - c.bytes_sent == c.sent * (98 + len(link[0]))
    assert {k: v.sent for k, v in real.per_kind.items()} == {k: v.sent for k, v in ref.per_kind.items()}


def test_an_address_in_use_is_an_input_error_without_hanging(trio):
    """Binding where another agent listens raises InputError at once, and the half-built transport leaks nothing."""
    key = new_private_key()
    peers = {"A9": Peer("A9", trio["A0"].addresses["A0"], public_key_bytes(key))}
    start = time.monotonic()
    with pytest.raises(InputError, match="cannot listen"):
        ZmqTransport({"A9": key}, peers)
    assert time.monotonic() - start < 5.0


def test_bind_must_name_local_agents():
    """A bind override for an agent that is not local is refused."""
    key = new_private_key()
    peers = {"A0": Peer("A0", "tcp://127.0.0.1:0", public_key_bytes(key))}
    with pytest.raises(InputError, match="not local"):
        ZmqTransport({"A0": key}, peers, bind={"A1": "tcp://127.0.0.1:0"})


def test_ipv6_loopback_round_trip():
    """Bracketed IPv6 addresses work like IPv4 ones."""
    import socket

    try:
        with socket.socket(socket.AF_INET6) as probe:
            probe.bind(("::1", 0))
    except OSError:
        pytest.skip("this machine has no IPv6 loopback")
    keys = {n: new_private_key() for n in ("A0", "A1")}
    peers = {n: Peer(n, "tcp://[::1]:0", public_key_bytes(k)) for n, k in keys.items()}
    with ZmqTransport({"A1": keys["A1"]}, peers) as a1:
        peers["A1"] = Peer("A1", a1.addresses["A1"], peers["A1"].public_key)
        with ZmqTransport({"A0": keys["A0"]}, peers) as a0:
            a0.send(hb("A0", "A1", 4), 0.0)
            assert [d.message.round for d in collect({"A1": a1}, 1)["A1"]] == [4]


MESH_CHILD = textwrap.dedent("""
    import json, sys, time
    from protocols.messages import BROADCAST, Heartbeat
    from protocols.peers import load_peers, load_private_key
    from protocols.zmq_transport import ZmqTransport
    name, key = load_private_key(sys.argv[1])
    n = int(sys.argv[3])
    with ZmqTransport({name: key}, load_peers(sys.argv[2]), bind={name: "tcp://127.0.0.1:0"}) as net:
        print(net.addresses[name], flush=True)
        peers = load_peers(sys.stdin.readline().strip())
        net.connect({other: p.address for other, p in peers.items() if other != name})
        for k in range(n):
            net.send(Heartbeat(sender=name, receiver=BROADCAST, round=k, t=0.0), time.time())
        got, deadline = [], time.monotonic() + 30
        while len(got) < n * (len(peers) - 1) and time.monotonic() < deadline:
            net.wait(0.05)
            got += [(d.sender, d.message.round) for d in net.poll(name, time.time())]
        print(json.dumps(sorted(got)), flush=True)
        sys.stdin.readline()  # every process has everything: now close
        print(json.dumps(net.stats().as_dict()), flush=True)
""")


def test_broadcast_mesh_of_processes_and_merged_books(tmp_path):
    """Three agent processes made from `write_keys` files broadcast to each other; each hears every other
    once per round, and the books they print merge into balanced stats with nothing in flight."""
    from sims.io.keyfiles import write_keys

    names, n = ["A0", "A1", "A2"], 20
    keys = write_keys(tmp_path, names, base_port=1)  # placeholder ports: each process binds a free one
    procs = {name: subprocess.Popen([sys.executable, "-c", MESH_CHILD, str(keys.private[name]), str(keys.peers),
                                     str(n)], cwd=ROOT, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
             for name in names}
    try:
        doc = json.loads(keys.peers.read_text())
        for name, p in procs.items():
            doc["peers"][name]["address"] = p.stdout.readline().strip()
        (tmp_path / "final.json").write_text(json.dumps(doc))
        for p in procs.values():
            p.stdin.write(f"{tmp_path / 'final.json'}\n")
            p.stdin.flush()
        heard = {name: json.loads(p.stdout.readline()) for name, p in procs.items()}
        for p in procs.values():
            p.stdin.write("close\n")
            p.stdin.flush()
        books = [TransportStats.from_dict(json.loads(p.stdout.readline())) for p in procs.values()]
    finally:
        for p in procs.values():
            stop(p)
    for name in names:
        assert heard[name] == sorted([other, k] for other in names if other != name for k in range(n))
    s = merge_stats(books)
    assert s.total.sent == s.total.delivered == 6 * n and s.total.in_flight == 0 and s.rejected == {}
    assert all(c.balanced() and c.sent == n for c in s.per_link.values()) and len(s.per_link) == 6


def test_per_link_faults_override_the_default():
    """A lossy override on one inbound link drops there only; the other link stays lossless."""
    transports, _ = open_loopback(["A0", "A1", "A2"], seed=5, links={("A0", "A2"): LinkConfig(drop=0.5)})
    try:
        for k in range(100):
            transports["A0"].send(hb("A0", BROADCAST, k), 0.0)
        got = collect(transports)
        s = merge_stats([t.stats() for t in transports.values()])
    finally:
        for t in transports.values():
            t.close()
    assert len(got["A1"]) == 100 and s.per_link[("A0", "A1")].dropped == 0
    assert len(got["A2"]) == 100 - s.per_link[("A0", "A2")].dropped and 25 <= len(got["A2"]) <= 75


def test_a_restarted_receiver_gets_what_was_sent_while_it_was_down():
    """Frames sent to a peer while its process is down wait in the sender's queue and reach its restarted process."""
    transports, peers = open_loopback(["A0", "A1"])
    a0, a1 = transports["A0"], transports["A1"]
    try:
        a0.send(hb("A0", "A1", 0), 0.0)
        assert len(collect({"A1": a1}, 1)["A1"]) == 1
        key = a1._local["A1"].signer._key
        a1.close()
        time.sleep(0.2)  # the sender notices the dead connection
        for k in range(1, 6):
            a0.send(hb("A0", "A1", k), 0.0)
        with ZmqTransport({"A1": key}, peers) as fresh:
            got = collect({"A1": fresh}, 5)["A1"]
        assert [d.message.round for d in got] == [1, 2, 3, 4, 5]
    finally:
        a0.close()


def test_a_process_that_never_closes_its_transport_still_exits_at_once():
    """Frames queued to an absent peer do not keep a process alive that exits without close() (linger 0)."""
    code = textwrap.dedent("""
        from protocols.auth import new_private_key, public_key_bytes
        from protocols.messages import Heartbeat
        from protocols.peers import Peer
        from protocols.zmq_transport import ZmqTransport
        key = new_private_key()
        peers = {"A0": Peer("A0", "tcp://127.0.0.1:0", public_key_bytes(key)),
                 "A1": Peer("A1", "tcp://127.0.0.1:9", public_key_bytes(new_private_key()))}
        net = ZmqTransport({"A0": key}, peers)
        for k in range(100):
            net.send(Heartbeat(sender="A0", receiver="A1", round=k, t=0.0), 0.0)
    """)
    subprocess.run([sys.executable, "-c", code], cwd=ROOT, check=True, timeout=30)


def test_receive_side_faults_equal_the_simulated_networks_for_the_same_seed():
    """With the same seed and the same sends, each link loses and duplicates exactly the copies the simulated
    network loses and duplicates (the real transport draws each link's stream as the simulation does)."""
    faults = LinkConfig(drop=0.3, duplicate=0.2)
    names = ("A0", "A1", "A2")
    sim = SimulatedNetwork(NetworkConfig(agents=names, link=faults), np.random.default_rng(11))
    transports, _ = open_loopback(list(names), seed=11, faults=faults)
    traffic = [hb(a, BROADCAST, k) for k in range(60) for a in names]
    try:
        for m in traffic:
            sim.send(m, 0.0)
            transports[m.sender].send(m, 0.0)
        got = collect(transports)
    finally:
        for t in transports.values():
            t.close()
    ref = sim.deliver(1.0)
    for name in names:
        real = sorted((d.sender, d.message.round, d.duplicate) for d in got[name])
        assert real == sorted((d.sender, d.message.round, d.duplicate) for d in ref[name])
        assert 0 < sum(dup for *_, dup in real) and len(real) != 120
