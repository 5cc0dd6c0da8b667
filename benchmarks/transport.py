"""The real transport against raw pyzmq, measured in the same run; and the cost of signing a frame.

Three measurements per payload size (default 100 B, 1 kB and 30 kB of message frame):

* **round trip**: a parent process and an echo process (spawned) on 127.0.0.1 play ping-pong; median
  seconds per round trip over ``--pings`` exchanges (after ``--warmup``). *Raw*: the same PUSH/PULL
  pattern (one PULL bound per side, one PUSH to the other) carrying the message's wire bytes as they
  are. *Ours*: :class:`protocols.zmq_transport.ZmqTransport` carrying the message (encode, sign,
  verify, replay check, decode on every hop; the echo re-signs).
* **throughput**: the parent sends ``--frames`` frames to the echo process as fast as it can;
  messages/s and MB/s of message frame from the first send to the last arrival (both processes
  read the machine's one monotonic clock). Queues are unbounded here (``hwm=0``), so nothing is
  dropped (``dropped`` says so).
* **signing overhead**, in one process: median microseconds to seal (encode + sign) and to admit
  (verify + replay check + decode) a frame, against the unsigned path (encode + decode) of the
  same message; ratio = (seal + admit) / (encode + decode).

Usage: ``python benchmarks/transport.py [--out DIR] [--sizes 100 1000 30000] [--pings N] [--frames N]``;
prints a line per size, and writes and prints ``DIR/transport.json`` (default ``out/benchmarks``).
"""

from __future__ import annotations

import argparse
import multiprocessing
import sys
import time
from dataclasses import dataclass
from typing import ClassVar

from _common import machine, median_seconds, parser, save  # noqa: I001  (pins threads before numpy)

import numpy as np


def build_parser() -> argparse.ArgumentParser:
    ap = parser(__doc__)
    ap.add_argument("--sizes", type=int, nargs="+", default=[100, 1000, 30000],
                    help="message frame sizes in bytes (default 100 1000 30000)")
    ap.add_argument("--pings", type=int, default=2000, help="round trips per size (default 2000)")
    ap.add_argument("--warmup", type=int, default=200, help="round trips not timed (default 200)")
    ap.add_argument("--frames", type=int, default=20000, help="frames per throughput run (default 20000; "
                                                               "a tenth for sizes over 10 kB)")
    ap.add_argument("--reps", type=int, default=3000, help="repetitions of the signing timings (default 3000)")
    return ap


# ---------------------------------------------------------------------------- the payload
def _blob_class():
    from protocols.messages import Message, register

    @register
    @dataclass(frozen=True, slots=True, eq=False, kw_only=True)
    class Blob(Message):
        """A benchmark message carrying ``data`` as it is."""

        KIND: ClassVar[str] = "bench.blob"
        data: bytes

    return Blob


def blob(size: int, sender: str = "P", receiver: str = "E"):
    """A message whose wire frame is exactly ``size`` bytes (at least the empty blob's size)."""
    Blob = _blob_class() if "bench.blob" not in _kinds() else _kinds()["bench.blob"]
    empty = Blob(sender=sender, receiver=receiver, round=0, data=b"").size_bytes
    return Blob(sender=sender, receiver=receiver, round=0, data=bytes(max(0, size - empty)))


def _kinds():
    from protocols.messages import registered_kinds

    return registered_kinds()


# ---------------------------------------------------------------------------- echo processes
def _raw_pair():
    """The raw side's sockets, as ZmqTransport sets them up: a bound PULL and a PUSH (unbounded queues here)."""
    import zmq

    ctx = zmq.Context()
    pull, push = ctx.socket(zmq.PULL), ctx.socket(zmq.PUSH)
    for s in (pull, push):
        s.setsockopt(zmq.LINGER, 0)
        s.setsockopt(zmq.SNDHWM, 0)
        s.setsockopt(zmq.RCVHWM, 0)
    pull.bind("tcp://127.0.0.1:*")
    return ctx, pull, push


def _raw_echo(addresses, ready, n_pings: int, n_frames: int) -> None:
    """Raw pyzmq side: PULL bound here, PUSH to the parent; echo ``n_pings`` frames, then count ``n_frames``."""
    import zmq

    ctx, pull, push = _raw_pair()
    push.connect(addresses["P"])
    ready.put(pull.getsockopt_string(zmq.LAST_ENDPOINT))
    for _ in range(n_pings):
        pull.poll(10_000)
        push.send(pull.recv(zmq.NOBLOCK))
    for _ in range(n_frames):
        pull.poll(10_000)
        pull.recv(zmq.NOBLOCK)
    ready.put(time.monotonic())  # CLOCK_MONOTONIC: one clock for every process of the machine
    push.send(b"done")
    ready.get()
    pull.close(), push.close(), ctx.term()


def _our_echo(peers, key_bytes: bytes, ready, n_pings: int, n_frames: int) -> None:
    """Our side: a ZmqTransport for agent E; echo ``n_pings`` messages, then count ``n_frames``."""
    from protocols.auth import private_key_from_bytes
    from protocols.zmq_transport import ZmqTransport

    Blob = _blob_class()
    with ZmqTransport({"E": private_key_from_bytes(key_bytes)}, peers, bind={"E": "tcp://127.0.0.1:0"},
                      hwm=0) as net:
        ready.put(net.addresses["E"])
        echoed = 0
        while echoed < n_pings:
            net.wait(10.0)
            for d in net.poll("E", 0.0):
                net.send(Blob(sender="E", receiver="P", round=d.message.round, data=d.message.data), 0.0)
                echoed += 1
        got = 0
        while got < n_frames:
            net.wait(10.0)
            got += len(net.poll("E", 0.0))
        ready.put(time.monotonic())
        net.send(Blob(sender="E", receiver="P", round=-1, data=b""), 0.0)
        ready.get()


# ---------------------------------------------------------------------------- measurements
def raw_run(size: int, pings: int, warmup: int, frames: int) -> dict:
    import zmq

    ctx = multiprocessing.get_context("spawn")
    frame = blob(size).to_bytes()
    zctx, pull, push = _raw_pair()
    ready = ctx.Queue()
    child = ctx.Process(target=_raw_echo, args=({"P": pull.getsockopt_string(zmq.LAST_ENDPOINT)}, ready,
                                                 pings + warmup, frames))
    child.start()
    try:
        push.connect(ready.get(timeout=60))
        rtt = []
        for i in range(pings + warmup):
            t0 = time.perf_counter()
            push.send(frame)
            pull.poll(10_000)
            pull.recv(zmq.NOBLOCK)
            if i >= warmup:
                rtt.append(time.perf_counter() - t0)
        t0 = time.monotonic()
        for _ in range(frames):
            push.send(frame)
        send_s = time.monotonic() - t0
        recv_s = ready.get(timeout=600) - t0
        pull.poll(60_000)
        pull.recv()
        ready.put("bye")
    finally:
        child.join(timeout=30)
        child.kill() if child.is_alive() else None
        pull.close(), push.close(), zctx.term()
    return _summary(size, len(frame), rtt, frames, send_s, recv_s, dropped=0)


def our_run(size: int, pings: int, warmup: int, frames: int) -> dict:
    from protocols.auth import new_private_key, private_key_bytes, public_key_bytes
    from protocols.peers import Peer
    from protocols.zmq_transport import ZmqTransport

    ctx = multiprocessing.get_context("spawn")
    keys = {"P": new_private_key(), "E": new_private_key()}
    peers = {n: Peer(n, "tcp://127.0.0.1:0", public_key_bytes(k)) for n, k in keys.items()}
    msg = blob(size)
    with ZmqTransport({"P": keys["P"]}, peers, hwm=0) as net:
        peers["P"] = Peer("P", net.addresses["P"], peers["P"].public_key)
        ready = ctx.Queue()
        child = ctx.Process(target=_our_echo, args=(peers, private_key_bytes(keys["E"]), ready, pings + warmup,
                                                    frames))
        child.start()
        try:
            net.connect({"E": ready.get(timeout=60)})
            rtt = []
            for i in range(pings + warmup):
                t0 = time.perf_counter()
                net.send(msg, 0.0)
                got = []
                while not got:
                    net.wait(10.0)
                    got = net.poll("P", 0.0)
                if i >= warmup:
                    rtt.append(time.perf_counter() - t0)
            t0 = time.monotonic()
            for _ in range(frames):
                net.send(msg, 0.0)
            send_s = time.monotonic() - t0
            recv_s = ready.get(timeout=600) - t0
            while not net.poll("P", 0.0):
                net.wait(10.0)
            ready.put("bye")
        finally:
            child.join(timeout=30)
            child.kill() if child.is_alive() else None
        frame_size = net.stats().total.bytes_sent // max(net.stats().total.sent, 1)
        dropped = net.stats().total.dropped
    return _summary(size, len(msg.to_bytes()), rtt, frames, send_s, recv_s, dropped, frame_size)


def _summary(size, message_bytes, rtt, frames, send_s, recv_s, dropped, wire_bytes=None) -> dict:
    return {
        "payload_bytes": size,
        "message_frame_bytes": message_bytes,
        "wire_frame_bytes": wire_bytes or message_bytes,
        "round_trip_median_us": 1e6 * float(np.median(rtt)),
        "round_trip_p90_us": 1e6 * float(np.quantile(rtt, 0.9)),
        "frames": frames,
        "dropped": dropped,
        "send_seconds": send_s,
        "receive_seconds": recv_s,
        "messages_per_s": frames / recv_s,
        "megabytes_per_s": frames * message_bytes / recv_s / 1e6,
    }


def median_us(fn, reps: int) -> float:
    return 1e6 * median_seconds(fn, reps, max(50, reps // 10))


def signing_overhead(size: int, reps: int) -> dict:
    """Median µs of seal and admit against encode and decode of the same message."""
    from protocols.auth import Gate, Signer, new_private_key, public_key_bytes
    from protocols.messages import decode

    key = new_private_key()
    msg = blob(size)
    signer = Signer("P", key)
    frames = [signer.seal(msg, 0.0) for _ in range(reps + max(50, reps // 10))]
    gate = Gate("E", {"P": public_key_bytes(key)}, window=len(frames) + 1)
    it = iter(frames)
    inner = msg.to_bytes()
    public, signature = key.verify_key, key.sign(inner).signature
    out = {
        "payload_bytes": size,
        "encode_us": median_us(msg.to_bytes, reps),
        "decode_us": median_us(lambda: decode(inner), reps),
        "seal_us": median_us(lambda: signer.seal(msg, 0.0), reps),
        "admit_us": median_us(lambda: gate.admit(next(it)), reps),
        "sign_only_us": median_us(lambda: key.sign(inner), reps),
        "verify_only_us": median_us(lambda: public.verify(inner, signature), reps),
    }
    out["ratio_signed_to_unsigned"] = (out["seal_us"] + out["admit_us"]) / (out["encode_us"] + out["decode_us"])
    out["overhead_us_per_frame"] = out["seal_us"] + out["admit_us"] - out["encode_us"] - out["decode_us"]
    return out


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from importlib import metadata

    info = machine()
    info["versions"].update({p: metadata.version(p) for p in ("pyzmq", "pynacl")})
    import zmq

    info["versions"]["libzmq"] = zmq.zmq_version()
    rows = []
    for size in args.sizes:
        frames = args.frames if size <= 10_000 else max(100, args.frames // 10)
        raw = raw_run(size, args.pings, args.warmup, frames)
        ours = our_run(size, args.pings, args.warmup, frames)
        sig = signing_overhead(size, args.reps)
        rows.append({"size": size, "raw": raw, "ours": ours, "signing": sig,
                     "round_trip_ratio": ours["round_trip_median_us"] / raw["round_trip_median_us"],
                     "throughput_ratio": ours["messages_per_s"] / raw["messages_per_s"]})
        print(f"{size:>7} B  rtt raw {raw['round_trip_median_us']:8.1f} us  ours {ours['round_trip_median_us']:8.1f} us"
              f"  ({rows[-1]['round_trip_ratio']:.2f}x)   msg/s raw {raw['messages_per_s']:9.0f}  ours "
              f"{ours['messages_per_s']:8.0f} ({rows[-1]['throughput_ratio']:.2f}x)   seal {sig['seal_us']:.1f} us"
              f" admit {sig['admit_us']:.1f} us vs encode+decode {sig['encode_us'] + sig['decode_us']:.1f} us"
              f" ({sig['ratio_signed_to_unsigned']:.1f}x)", flush=True)
    save("transport", {"benchmark": "transport", "parameters": {**vars(args), "out": str(args.out)}, "machine": info,
                       "rows": rows}, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
