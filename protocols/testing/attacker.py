"""An attacker for live tests: floods a running agent's socket with frames it must refuse.

:func:`flood` connects to an agent's inbound address like any peer and sends ``n_frames`` hostile
frames drawn from :data:`ATTACKS`, each of which the agent must refuse with a known reason; the
returned :class:`FloodReport` says how many of each to expect in the agent's ``stats().rejected``.
:class:`Tap` plays a peer that only listens, to capture genuine frames for replay;
:func:`raw_tcp_garbage` writes bytes that are not ZeroMQ framing on a plain TCP connection (the socket
library drops the connection, or what it reads as frames the agent refuses as ``malformed``).

To point it at launched agents: list an extra peer (say ``EVE``) in the peers file with a key the
attacker holds and the address of a :class:`Tap`; every broadcast reaches the tap, and EVE's key
lets the attacker try to speak for other members (``impersonation``)::

    with Tap("tcp://127.0.0.1:47999") as eve:
        ...  # agents run and broadcast
        captured = eve.frames(50, timeout=5.0)
    report = flood(agent_address, 100_000, np.random.default_rng(0), senders=list(peers),
                   captured=captured, insider=("EVE", eve_private_bytes))
    # later: agent's stats().rejected == report.expected (plus anything else it refused)
"""

from __future__ import annotations

import socket as pysocket
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import zmq

from protocols.auth import ENVELOPE_MAGIC, ENVELOPE_VERSION, parse, private_key_from_bytes, seal
from protocols.messages import BROADCAST, Heartbeat

__all__ = ["ATTACKS", "FloodReport", "flood", "Tap", "raw_tcp_garbage", "as_expected", "record_peak_rss"]

#: attack -> the reason the receiver must refuse it with
ATTACKS: Mapping[str, str] = {
    "random": "malformed",  # random bytes
    "truncated": "malformed",  # a genuine or forged envelope cut short
    "padded": "malformed",  # ... with bytes appended
    "old_version": "malformed",  # ... with another envelope version
    "forged": "bad_signature",  # a member's name, signed with a key that is not the member's
    "bitflip": "replay",  # a genuine frame (already admitted) with one byte of its message or signature changed:
    # its (epoch, seq) is no longer fresh, which the receiver checks before the signature
    "impersonation": "bad_signature",  # an insider's valid signature on a message from another member
    "unknown_sender": "unknown_sender",  # a name not in the peers file
    "replay": "replay",  # a genuine frame sent again
}
_NEEDS_CAPTURE = ("bitflip", "replay")


@dataclass(frozen=True)
class FloodReport:
    """What a flood sent.

    Attributes
    ----------
    sent : int
        Frames handed to the socket (all of them, unless ``timeout`` ran out).
    attacks : Mapping[str, int]
        Frames sent per attack name (:data:`ATTACKS`).
    expected : Mapping[str, int]
        Frames the target must refuse, per reason.
    """

    sent: int
    attacks: Mapping[str, int] = field(default_factory=dict)
    expected: Mapping[str, int] = field(default_factory=dict)


def as_expected(rejected: Mapping[str, int]) -> dict[str, int]:
    """A receiver's ``rejected`` counts in the terms of :attr:`FloodReport.expected`.

    Frames that reach the signature check from a connection that already sent refused frames may
    be refused as ``rate`` instead (:class:`protocols.admission.SuspectBudget`); every hostile
    frame that reaches that check is a ``bad_signature`` one, so ``rate`` is counted there.
    """
    out = {k: int(v) for k, v in rejected.items() if v and k != "rate"}
    if rejected.get("rate"):
        out["bad_signature"] = out.get("bad_signature", 0) + int(rejected["rate"])
    return dict(sorted(out.items()))


def _forged(rng: np.random.Generator, sender: str) -> bytes:
    """A well-formed envelope from ``sender`` signed with a random key, with a fresh (epoch, seq), sent now.

    The epoch is above any clock-derived one and ``sent_at`` is the attacker's clock, so that the
    receiver cannot refuse it as a replay or as stale before checking its signature (which it does
    first when it can: a cheaper refusal).
    """
    key = private_key_from_bytes(rng.bytes(32))
    inner = Heartbeat(sender=sender, receiver=BROADCAST, round=int(rng.integers(0, 2**31)), t=0.0).to_bytes()
    return seal(key, sender, 2**63 + int(rng.integers(0, 2**62)), int(rng.integers(0, 2**62)), time.time(), inner)


def _frame(attack: str, rng: np.random.Generator, senders: Sequence[str], captured: Sequence[bytes],
           insider) -> bytes:
    """One hostile frame of kind ``attack``."""
    base = captured[int(rng.integers(len(captured)))] if captured else None
    if attack == "random":
        data = rng.bytes(int(rng.integers(0, 2048)))
        return data if not data.startswith(ENVELOPE_MAGIC) else b"\x00" + data
    if attack in ("truncated", "padded", "old_version"):
        frame = base if base is not None else _forged(rng, senders[int(rng.integers(len(senders)))])
        if attack == "truncated":
            return frame[: int(rng.integers(0, len(frame)))]
        if attack == "padded":
            return frame + rng.bytes(int(rng.integers(1, 64)))
        version = int(rng.choice([v for v in range(256) if v != ENVELOPE_VERSION]))
        return frame[:4] + bytes([version]) + frame[5:]
    if attack == "forged":
        return _forged(rng, senders[int(rng.integers(len(senders)))])
    if attack == "bitflip":
        env = parse(base)
        start = len(env.signed) - len(env.inner)  # inside the inner frame or the signature
        pos = int(rng.integers(start, len(base)))
        return base[:pos] + bytes([base[pos] ^ int(rng.integers(1, 256))]) + base[pos + 1:]
    if attack == "impersonation":
        name, raw = insider
        victim = [s for s in senders if s != name][int(rng.integers(len(senders) - 1))]
        inner = Heartbeat(sender=victim, receiver=BROADCAST, round=0, t=0.0).to_bytes()
        # an epoch above any clock-derived one, so the frame is fresh and refused for whom it speaks
        return seal(private_key_from_bytes(raw), name, 2**63 + int(rng.integers(0, 2**62)), 0, time.time(), inner)
    if attack == "unknown_sender":
        return _forged(rng, "intruder-" + rng.bytes(6).hex())
    if attack == "replay":
        return base
    raise ValueError(f"unknown attack {attack!r}")


def flood(
    address: str,
    n_frames: int,
    rng: np.random.Generator,
    *,
    senders: Sequence[str],
    captured: Sequence[bytes] = (),
    insider: tuple[str, bytes] | None = None,
    attacks: Sequence[str] | None = None,
    timeout: float = 60.0,
) -> FloodReport:
    """Send ``n_frames`` hostile frames to the agent listening at ``address``.

    Parameters
    ----------
    address : str
        The target's inbound address (``tcp://HOST:PORT``).
    n_frames : int
        How many frames to send; each attack is drawn uniformly from ``attacks``.
    rng : numpy.random.Generator
        Draws the attacks and their bytes.
    senders : sequence of str
        Names in the target's peers file (``forged`` frames claim them).
    captured : sequence of bytes
        Genuine envelopes the target has already admitted (e.g. from a :class:`Tap`); without them
        ``bitflip`` and ``replay`` are left out.
    insider : (str, bytes), optional
        A member's name and raw private key held by the attacker; enables ``impersonation``
        (needs at least two ``senders``).
    attacks : sequence of str, optional
        Which attacks to use (default: every one the arguments allow).
    timeout : float
        Give up sending after this many seconds (a target that stopped reading).
    """
    allowed = [a for a in (attacks or ATTACKS) if (captured or a not in _NEEDS_CAPTURE)
               and (a != "impersonation" or (insider is not None and len(senders) >= 2))]
    if not allowed or not senders:
        raise ValueError("no attack is possible with these arguments")
    ctx = zmq.Context()
    sock = ctx.socket(zmq.PUSH)
    sock.setsockopt(zmq.SNDTIMEO, 1000)
    sock.connect(address)
    counts: dict[str, int] = {}
    sent = 0
    deadline = time.monotonic() + timeout
    try:
        for _ in range(int(n_frames)):
            attack = allowed[int(rng.integers(len(allowed)))]
            frame = _frame(attack, rng, senders, captured, insider)
            while True:
                try:
                    sock.send(frame)
                    break
                except zmq.Again:
                    if time.monotonic() > deadline:
                        raise TimeoutError from None
            counts[attack] = counts.get(attack, 0) + 1
            sent += 1
    except TimeoutError:
        pass
    finally:
        sock.close(linger=int(max(0.0, deadline - time.monotonic()) * 1000))  # let queued frames out
        ctx.term()
    expected: dict[str, int] = {}
    for attack, n in counts.items():
        expected[ATTACKS[attack]] = expected.get(ATTACKS[attack], 0) + n
    return FloodReport(sent, dict(sorted(counts.items())), dict(sorted(expected.items())))


class Tap:
    """A peer that only listens: binds ``address`` and keeps every frame sent to it (genuine frames to replay).

    Use as a context manager; :meth:`frames` collects what has arrived.
    """

    def __init__(self, address: str):
        self._ctx = zmq.Context()
        self._sock = self._ctx.socket(zmq.PULL)
        self._sock.setsockopt(zmq.LINGER, 0)
        try:
            self._sock.bind(address[:-2] + ":*" if address.endswith(":0") else address)
        except zmq.ZMQError:
            self.close()
            raise
        self.address = self._sock.getsockopt_string(zmq.LAST_ENDPOINT)

    def frames(self, n_frames: int, timeout: float) -> list[bytes]:
        """Up to ``n_frames`` frames, waiting at most ``timeout`` seconds for them."""
        out: list[bytes] = []
        deadline = time.monotonic() + timeout
        while len(out) < n_frames and (left := deadline - time.monotonic()) > 0:
            if self._sock.poll(int(left * 1000) + 1):
                out.append(self._sock.recv())
        return out

    def close(self) -> None:
        self._sock.close()
        self._ctx.term()

    def __enter__(self) -> "Tap":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def raw_tcp_garbage(address: str, n_bytes: int, rng: np.random.Generator) -> None:
    """Open a plain TCP connection to a ``tcp://HOST:PORT`` address and write random bytes into it."""
    host, port = address.removeprefix("tcp://").rsplit(":", 1)
    with pysocket.create_connection((host.strip("[]"), int(port)), timeout=5.0) as conn:
        try:
            conn.sendall(rng.bytes(int(n_bytes)))
        except OSError:  # the peer hung up on the garbage: what it should do
            pass


def main(argv: list[str] | None = None) -> int:
    """``python -m protocols.testing.attacker ADDRESS --peers PEERS.json [...]``: flood one agent, print the report."""
    import argparse
    import json

    from protocols.auth import private_key_bytes
    from protocols.peers import load_peers, load_private_key

    parser = argparse.ArgumentParser(prog="python -m protocols.testing.attacker", description=__doc__.split("\n\n")[0])
    parser.add_argument("address", help="the target agent's inbound address, tcp://HOST:PORT")
    parser.add_argument("--peers", required=True, help="the target's peers file (forged frames claim its names)")
    parser.add_argument("--frames", type=int, default=10_000, help="hostile frames to send (default 10000)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the attack mix and bytes (default 0)")
    parser.add_argument("--insider", metavar="KEYFILE", help="a member's key file the attacker holds (impersonation)")
    parser.add_argument("--tap", metavar="ADDRESS", help="listen here first (the insider's peers-file address) ...")
    parser.add_argument("--capture", type=int, default=20, help="... for this many genuine frames (default 20)")
    parser.add_argument("--capture-timeout", type=float, default=10.0, help="... or this many seconds (default 10)")
    args = parser.parse_args(argv)
    senders = list(load_peers(args.peers))
    insider = None
    if args.insider:
        name, key = load_private_key(args.insider)
        insider = (name, private_key_bytes(key))
    captured: list[bytes] = []
    if args.tap:
        with Tap(args.tap) as tap:
            captured = tap.frames(args.capture, args.capture_timeout)
    report = flood(args.address, args.frames, np.random.default_rng(args.seed), senders=senders, captured=captured,
                   insider=insider)
    print(json.dumps({"sent": report.sent, "captured": len(captured), "attacks": report.attacks,
                      "expected": report.expected}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())


def record_peak_rss(pids: Sequence[int], peak: dict) -> None:
    """Raise ``peak[pid]`` to each live process's resident memory now (bytes, from ``/proc/PID/status``)."""
    for pid in pids:
        try:
            for line in Path(f"/proc/{pid}/status").read_text().splitlines():
                if line.startswith("VmRSS:"):
                    peak[pid] = max(peak.get(pid, 0), int(line.split()[1]) * 1024)
        except OSError:
            pass  # the process is gone
