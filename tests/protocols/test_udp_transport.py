"""The datagram transport over real loopback sockets: delivery, large frames in pieces, refusals, seeded faults."""

from __future__ import annotations

import socket
import time

import numpy as np
import pytest

from decentral.errors import InputError
from protocols.auth import new_private_key, public_key_bytes
from protocols.baselines.flood import RawStep
from protocols.datagrams import Reassembler, split_frame
from protocols.messages import BROADCAST, Heartbeat
from protocols.network import LinkConfig
from protocols.peers import Peer
from protocols.transport import Transport, merge_stats
from protocols.udp_transport import UdpTransport, udp_endpoint


def _mesh(names, **kwargs):
    keys = {n: new_private_key() for n in names}
    peers = {n: Peer(n, "tcp://127.0.0.1:0", public_key_bytes(k)) for n, k in keys.items()}
    ts = {n: UdpTransport({n: keys[n]}, peers, **kwargs) for n in names}
    table = {n: ts[n].addresses[n] for n in names}
    for n, t in ts.items():
        t.connect({o: a for o, a in table.items() if o != n})
    return ts, keys, table


def _collect(ts, n, timeout=10.0):
    got = {name: [] for name in ts}
    deadline = time.monotonic() + timeout
    while sum(map(len, got.values())) < n and time.monotonic() < deadline:
        for name, t in ts.items():
            t.wait(0.005)
            got[name] += t.poll(name, time.monotonic())
    return got


@pytest.fixture
def trio():
    ts, _, _ = _mesh(["A0", "A1", "A2"])
    yield ts
    for t in ts.values():
        t.close()


def test_is_a_transport(trio):
    """It implements the transport interface."""
    assert isinstance(trio["A0"], Transport) and trio["A0"].agents == ("A0",)


def test_broadcast_arrives_once_per_peer_and_books_balance(trio):
    """A broadcast reaches each other agent once; the merged books have nothing in flight."""
    trio["A0"].send(Heartbeat(sender="A0", receiver=BROADCAST, round=1, t=0.0), time.monotonic())
    got = _collect(trio, 2)
    assert [len(got[n]) for n in ("A0", "A1", "A2")] == [0, 1, 1]
    total = merge_stats([t.stats() for t in trio.values()]).total
    assert total.sent == total.delivered == 2 and total.in_flight == 0


def test_a_frame_larger_than_a_datagram_arrives_whole(trio):
    """A 160 kB message crosses as many datagrams and arrives equal to what was sent."""
    uvr = np.arange(5000 * 3, dtype=float).reshape(-1, 3)
    msg = RawStep(sender="A0", receiver="A1", round=2, t=0.0, ids=np.arange(5000), uvr=uvr, odometry=np.zeros(0))
    trio["A0"].send(msg, time.monotonic())
    [d] = _collect(trio, 1)["A1"]
    assert np.array_equal(d.message.uvr, uvr)


def test_forged_and_garbage_datagrams_are_refused_and_counted(trio):
    """A frame signed by the wrong key and a datagram of garbage are refused by reason, never delivered."""
    host, port = udp_endpoint(trio["A1"].addresses["A1"])
    raw = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        raw.sendto(b"\x00garbage", (host, port))
        from protocols.auth import Signer

        frame = Signer("A0", new_private_key()).seal(Heartbeat(sender="A0", receiver="A1", round=1, t=0.0), 0.0)
        raw.sendto(split_frame(frame, 1200, 1)[0], (host, port))
    finally:
        raw.close()
    deadline = time.monotonic() + 5
    while sum(trio["A1"].stats().rejected.values()) < 2 and time.monotonic() < deadline:
        trio["A1"].wait(0.01)
        assert trio["A1"].poll("A1", time.monotonic()) == []
    assert trio["A1"].stats().rejected.get("malformed") == 1 and trio["A1"].stats().rejected.get("bad_signature") == 1


def test_receive_side_loss_is_seeded():
    """The same seed drops the same copies; drops are counted as loss."""
    outcomes = []
    for _ in range(2):
        ts, _, _ = _mesh(["A0", "A1"], rng=np.random.default_rng(5), faults=LinkConfig(drop=0.5))
        try:
            for k in range(40):
                ts["A0"].send(Heartbeat(sender="A0", receiver="A1", round=k, t=0.0), time.monotonic())
            got = []
            deadline = time.monotonic() + 5
            while ts["A1"].stats().total.dropped + len(got) < 40 and time.monotonic() < deadline:
                ts["A1"].wait(0.01)
                got += ts["A1"].poll("A1", time.monotonic())
            outcomes.append(sorted(d.message.round for d in got))
        finally:
            for t in ts.values():
                t.close()
    assert outcomes[0] == outcomes[1] and 5 < len(outcomes[0]) < 35


def test_reassembler_bounds_frames_in_progress_and_expires_them():
    """Pieces that never complete are dropped after the timeout and counted."""
    parts = Reassembler(max_frame_bytes=10_000, timeout=1.0, per_source=2)
    for fid in range(3):
        assert parts.add("s", split_frame(b"y" * 3000, 1200, fid)[0], 0.0) is None
    assert parts.expire(5.0) == 3  # one pushed out by the per-source bound, two timed out


def test_parity_rebuilds_one_lost_datagram_per_group_in_any_order():
    """With one parity datagram per four pieces (interleaved groups), a frame loses nothing when each group
    misses at most one of its datagrams, whatever arrives first; two losses in one group lose the frame.
    The parity that arrives after its frame is complete is not counted as an incomplete frame."""
    rng = np.random.default_rng(3)
    frame = rng.bytes(20_000)
    parts = split_frame(frame, 1200, 9)
    count = -(-len(frame) // (1200 - 17))
    groups = -(-count // 4)
    assert len(parts) == count + groups
    one_per_group = [[i for i in range(k * groups, (k + 1) * groups) if i < count] for k in range(4)]  # i mod groups
    for lost in [[i] for i in range(len(parts))] + one_per_group:
        r = Reassembler(max_frame_bytes=100_000)
        order = [j for j in rng.permutation(len(parts)) if j not in lost]
        got = [f for j in order if (f := r.add("s", parts[j], 0.0)) is not None]
        assert got == [frame] and r.expire(10.0) == 0
    r = Reassembler(max_frame_bytes=100_000)
    assert all(r.add("s", p, 0.0) is None for j, p in enumerate(parts) if j not in (0, groups))  # both in group 0
    assert r.expire(10.0) == 1


def test_pieces_that_disagree_with_their_header_are_refused():
    """A piece whose frame length or count differs from its frame's first piece is malformed, not a crash."""
    from protocols.auth import Rejected
    from protocols.datagrams import HEADER

    parts = split_frame(b"z" * 5000, 1200, 4)
    _, version, fid, index, count, groups, length = HEADER.unpack_from(parts[1])
    forged = HEADER.pack(b"DG", version, fid, index, count, groups, length + 1) + parts[1][HEADER.size:]
    r = Reassembler(max_frame_bytes=100_000)
    assert r.add("s", parts[0], 0.0) is None
    with pytest.raises(Rejected, match="changed"):
        r.add("s", forged, 0.0)
    short = split_frame(b"q" * 3000, 1200, 5)
    _, version, fid, index, count, groups, length = HEADER.unpack_from(short[0])
    lie = [HEADER.pack(b"DG", version, fid, i, count, groups, length + 5000) + p[HEADER.size:] for i, p in enumerate(short)]
    r = Reassembler(max_frame_bytes=100_000)
    with pytest.raises(Rejected, match="length"):
        for piece in lie[:count]:
            r.add("s", piece, 0.0)
    # a data piece longer than its group's parity (a forged datagram) is refused, not a crash of the rebuild
    big = split_frame(b"w" * 5000, 1200, 6)
    _, version, fid, index, count, groups, length = HEADER.unpack_from(big[0])
    long_piece = HEADER.pack(b"DG", version, fid, groups, count, groups, length) + b"v" * 1500
    r = Reassembler(max_frame_bytes=100_000)
    with pytest.raises(Rejected, match="length"):
        for piece in [long_piece] + [p for j, p in enumerate(big) if j not in (0, groups)]:
            r.add("s", piece, 0.0)


def test_ipc_address_has_no_datagram_form():
    """An ipc:// peer address is an input error for the datagram transport."""
    with pytest.raises(InputError):
        udp_endpoint("ipc:///tmp/x")


def _send_raw(transport, name, frames):
    host, port = udp_endpoint(transport.addresses[name])
    raw = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        for i, frame in enumerate(frames):
            for piece in split_frame(frame, 1200, 1000 + i):
                raw.sendto(piece, (host, port))
    finally:
        raw.close()


def _drain(transport, name, refused, timeout=5.0):
    deadline = time.monotonic() + timeout
    while sum(transport.stats().rejected.values()) < refused and time.monotonic() < deadline:
        transport.wait(0.01)
        assert transport.poll(name, time.time()) == []
    return transport.stats().rejected


def test_a_genuine_frame_of_an_earlier_run_is_refused_as_stale_with_a_clock_tolerance():
    """With a clock tolerance, a frame signed with the right key 60 s before the receiver started is refused
    as ``stale`` (a recorded earlier run); the receiver reports the sender's clock offset."""
    from protocols.auth import Signer

    ts, keys, _ = _mesh(["A0", "A1"], max_age=5.0)
    try:
        now = time.time()
        old = Signer("A0", keys["A0"], epoch=int((now - 70) * 1e9)).seal(
            Heartbeat(sender="A0", receiver="A1", round=1, t=0.0), now - 60)
        _send_raw(ts["A1"], "A1", [old])
        assert _drain(ts["A1"], "A1", 1).get("stale") == 1
        lo, _ = ts["A1"].clock_offsets("A1")["A0"]
        assert 59 < lo < 70
    finally:
        for t in ts.values():
            t.close()


def test_a_source_of_forged_frames_gets_a_bounded_number_of_signature_checks():
    """Forged frames (a member's name, a wrong key) from one source address: after the first refusal the source
    is suspect, and past the budget its frames are refused as ``rate`` without a signature check."""
    from protocols.auth import Signer

    ts, _, _ = _mesh(["A0", "A1"], suspect_rate=1.0)
    try:
        forger = Signer("A0", new_private_key())
        frames = [forger.seal(Heartbeat(sender="A0", receiver="A1", round=k, t=0.0), time.time()) for k in range(200)]
        _send_raw(ts["A1"], "A1", frames)
        rejected = _drain(ts["A1"], "A1", 200)
        assert sum(rejected.values()) == 200
        assert rejected.get("rate", 0) > 100  # the budget (burst 50, 1 check/s) checked at most ~55 of them
        assert rejected.get("bad_signature", 0) < 100
    finally:
        for t in ts.values():
            t.close()
