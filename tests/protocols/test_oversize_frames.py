"""Frames over the size limit are refused and counted as ``oversize`` by both real transports; peers that
close their connections are not counted."""

from __future__ import annotations

import socket
import time

import zmq

from protocols.auth import new_private_key, public_key_bytes
from protocols.datagrams import split_frame
from protocols.messages import Heartbeat
from protocols.peers import Peer
from protocols.udp_transport import UdpTransport, udp_endpoint
from protocols.zmq_transport import open_loopback

LIMIT = 20_000


def _poll_until(t, name: str, done, timeout: float = 5.0) -> list:
    got, deadline = [], time.monotonic() + timeout
    while not done() and time.monotonic() < deadline:
        t.wait(0.01)
        got += t.poll(name, time.monotonic())
    return got


def _push(address: str, frames: list[bytes], close_after: float = 0.3) -> None:
    """A raw ZeroMQ sender (no key): connect, send ``frames``, wait, close."""
    ctx = zmq.Context()
    try:
        s = ctx.socket(zmq.PUSH)
        s.setsockopt(zmq.LINGER, 1000)
        s.connect(address)
        for f in frames:
            s.send(f)
        time.sleep(close_after)
        s.close()
    finally:
        ctx.term()


def test_zmq_frames_over_the_limit_are_counted_and_genuine_frames_still_arrive():
    """Three frames over ``max_frame_bytes`` from a raw sender are counted ``oversize`` (one dropped connection
    each); a genuine peer's heartbeat sent after them still arrives."""
    ts, _ = open_loopback(["A0", "A1"], max_frame_bytes=LIMIT)
    try:
        address = ts["A1"].addresses["A1"]
        for _ in range(3):
            _push(address, [b"x" * (5 * LIMIT)])
        ts["A0"].send(Heartbeat(sender="A0", receiver="A1", round=1, t=0.0), time.time())
        got = _poll_until(ts["A1"], "A1", lambda: ts["A1"].stats().rejected.get("oversize", 0) >= 3)
        got += _poll_until(ts["A1"], "A1", lambda: bool(got), timeout=2.0)
        assert ts["A1"].stats().rejected.get("oversize") == 3
        assert [d.message.round for d in got] == [1]
    finally:
        for t in ts.values():
            t.close()


def test_zmq_peers_that_close_their_connections_are_not_counted_as_oversize():
    """A raw sender of small garbage that closes, and a genuine peer that closes its transport: no ``oversize``."""
    ts, _ = open_loopback(["A0", "A1"], max_frame_bytes=LIMIT)
    try:
        _push(ts["A1"].addresses["A1"], [b"garbage", b"y" * 100])
        ts["A0"].send(Heartbeat(sender="A0", receiver="A1", round=1, t=0.0), time.time())
        _poll_until(ts["A1"], "A1", lambda: ts["A1"].stats().total.delivered >= 1)
        ts["A0"].close()
        _poll_until(ts["A1"], "A1", lambda: False, timeout=0.5)
        rejected = ts["A1"].stats().rejected
        assert rejected.get("malformed", 0) == 2 and "oversize" not in rejected, dict(rejected)
    finally:
        for t in ts.values():
            t.close()


def test_udp_frames_over_the_limit_are_refused_as_oversize():
    """Pieces of a frame larger than ``max_frame_bytes`` are refused ``oversize`` before it is whole."""
    keys = {n: new_private_key() for n in ("A0", "A1")}
    peers = {n: Peer(n, "tcp://127.0.0.1:0", public_key_bytes(k)) for n, k in keys.items()}
    t = UdpTransport({"A1": keys["A1"]}, peers, max_frame_bytes=LIMIT)
    raw = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        for piece in split_frame(b"z" * (3 * LIMIT), 1200, 7):
            raw.sendto(piece, udp_endpoint(t.addresses["A1"]))
        _poll_until(t, "A1", lambda: t.stats().rejected.get("oversize", 0) >= 1)
        assert t.stats().rejected.get("oversize", 0) >= 1 and t.stats().total.delivered == 0
    finally:
        raw.close()
        t.close()
