"""A live attack on a running transport: another process floods its socket while a peer keeps talking to it."""

from __future__ import annotations

import multiprocessing
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np
import pytest

from protocols.auth import new_private_key, private_key_bytes, public_key_bytes
from protocols.messages import BROADCAST, Heartbeat
from protocols.peers import Peer
from protocols.testing.attacker import ATTACKS, Tap, as_expected, flood, raw_tcp_garbage
from protocols.zmq_transport import ZmqTransport


def hb(a: str, b: str, k: int) -> Heartbeat:
    return Heartbeat(sender=a, receiver=b, round=k, t=0.0)


def table(keys: dict, addresses: dict) -> dict[str, Peer]:
    """A peers table: every key's agent, at its address in ``addresses`` or at any free port."""
    return {n: Peer(n, addresses.get(n, "tcp://127.0.0.1:0"), public_key_bytes(k)) for n, k in keys.items()}


def attack(n_frames: int, seed: int) -> None:
    """A0 and A1 run in this process, EVE (an insider key the attacker holds) only listens; a spawned
    process floods A1 with ``n_frames`` hostile frames while A0 keeps sending to A1."""
    keys = {name: new_private_key() for name in ("A0", "A1", "EVE")}
    got = []
    with Tap("tcp://127.0.0.1:0") as eve, ZmqTransport({"A1": keys["A1"]}, table(keys, {"EVE": eve.address})) as a1:
        a0 = ZmqTransport({"A0": keys["A0"]}, table(keys, {"EVE": eve.address, **a1.addresses}))

        def pump(until, seconds: float = 30) -> None:
            deadline = time.monotonic() + seconds
            while not until() and time.monotonic() < deadline:
                a1.wait(0.002)
                got.extend(a1.poll("A1", time.monotonic()))

        with a0:
            for k in range(20):  # genuine broadcasts reach A1 and EVE: EVE's copies are the captured frames
                a0.send(hb("A0", BROADCAST, k), 0.0)
            pump(lambda: len(got) == 20)
            captured = eve.frames(20, timeout=10)
            assert len(captured) == 20 and a1.stats().rejected == {}
            with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
                job = pool.submit(flood, a1.addresses["A1"], n_frames, np.random.default_rng(seed),
                                  senders=["A0", "A1", "EVE"], captured=captured,
                                  insider=("EVE", private_key_bytes(keys["EVE"])))
                k = 20
                deadline = time.monotonic() + 600
                while not job.done() and time.monotonic() < deadline:  # legitimate traffic all along
                    a0.send(hb("A0", "A1", k), 0.0)
                    k += 1
                    pump(lambda: False, seconds=0.001)
                report = job.result()
            pump(lambda: sum(a1.stats().rejected.values()) >= report.sent and len(got) == k)
        rejected = a1.stats().rejected
    assert report.sent == n_frames and set(report.attacks) == set(ATTACKS)
    assert as_expected(rejected) == report.expected  # frames past the budget of checks: `rate`, not verified
    assert [d.message.round for d in got] == list(range(k)) and {d.sender for d in got} == {"A0"}
    assert k > 20  # A0 kept talking during the flood


def test_live_flood_is_refused_frame_by_frame_and_legit_traffic_flows():
    """10,000 hostile frames from another process: each refused for its reason, none fatal, A0's frames
    all delivered."""
    attack(10_000, seed=1)


@pytest.mark.slow
def test_live_flood_of_100k_frames():
    """100,000 hostile frames from another process: each refused for its reason, none fatal, A0's frames
    all delivered."""
    attack(100_000, seed=2)


def test_raw_tcp_garbage_does_not_disturb_the_transport():
    """Raw bytes on a TCP connection (not ZeroMQ's framing) are dropped by the socket library (counted
    ``oversize``: a length the bytes spell out over the limit) or refused as malformed; the agent keeps working."""
    keys = {name: new_private_key() for name in ("A0", "A1")}
    with ZmqTransport({"A1": keys["A1"]}, table(keys, {})) as a1:
        raw_tcp_garbage(a1.addresses["A1"], 100_000, np.random.default_rng(0))
        with ZmqTransport({"A0": keys["A0"]}, table(keys, a1.addresses)) as a0:
            a0.send(hb("A0", "A1", 1), 0.0)
            deadline, got = time.monotonic() + 10, []
            while not got and time.monotonic() < deadline:
                a1.wait(0.01)
                got = a1.poll("A1", 0.0)
        assert [d.message.round for d in got] == [1] and set(a1.stats().rejected) <= {"malformed", "oversize"}


def test_attacker_command_line(tmp_path):
    """`python -m protocols.testing.attacker` floods an agent named in a peers file and prints what to expect."""
    import json
    import subprocess
    import sys

    from protocols.peers import peers_json

    keys = {name: new_private_key() for name in ("A0", "A1")}
    with ZmqTransport({"A1": keys["A1"]}, table(keys, {})) as a1:
        peers = table(keys, {"A0": "tcp://127.0.0.1:1", **a1.addresses})
        (tmp_path / "peers.json").write_text(json.dumps(peers_json(peers)))
        out = subprocess.run([sys.executable, "-m", "protocols.testing.attacker", a1.addresses["A1"], "--peers",
                              str(tmp_path / "peers.json"), "--frames", "300", "--seed", "3"],
                             capture_output=True, text=True, timeout=120, check=True)
        report = json.loads(out.stdout)
        deadline = time.monotonic() + 30
        while sum(a1.stats().rejected.values()) < 300 and time.monotonic() < deadline:
            a1.wait(0.01)
            assert a1.poll("A1", 0.0) == []
        assert report["sent"] == 300 and as_expected(a1.stats().rejected) == report["expected"]
