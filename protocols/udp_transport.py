"""A datagram transport: the same signed frames as :mod:`protocols.zmq_transport`, over UDP.

Over a lossy radio, TCP turns each lost packet into a stall of every later frame on that connection
(head-of-line blocking: a retransmission timeout of 200 ms or more, doubled on each loss in a row),
while the consensus protocol already treats a lost frame as a failure it recovers from (resends,
timeouts, newest-value-wins). Here a lost datagram is just a lost frame; the frames behind it arrive.

- **Addresses**: the peers file's ``tcp://HOST:PORT`` names the UDP port ``PORT`` on ``HOST`` (a peers
  file serves both transports); ``ipc://`` addresses have no datagram form and are refused.
- **Frames**: every frame is the signed envelope of :mod:`protocols.auth` (:class:`~protocols.auth.Signer`
  on the way out, :class:`~protocols.auth.Gate` on the way in: signature, sender, epoch and sequence
  number, replays refused), cut into datagrams of at most ``mtu`` bytes (:mod:`protocols.datagrams`) so
  that no datagram is fragmented by IP, with one parity datagram per ``parity_group`` pieces so that a
  frame survives one lost datagram in each group (a radio loses datagrams, and a frame of many pieces
  would otherwise be lost whenever any one of them is); a frame whose pieces cannot be put together
  within ``reassembly`` seconds is lost (counted ``incomplete``). Frames above ``max_frame_bytes`` are refused.
- **Faults and books**: receive-side faults (``drop``, ``duplicate``, ``latency``, ``jitter``) are drawn
  per link as :class:`~protocols.zmq_transport.ZmqTransport` and the simulated network draw them
  (:mod:`protocols.receive_faults`, six draws per admitted copy); the counting convention is
  :mod:`protocols.transport`'s, split between the sending and the receiving process.
"""

from __future__ import annotations

import os
import select
import socket
import time
from typing import Mapping

import numpy as np
from nacl.signing import SigningKey

from decentral.errors import InputError, ProtocolError
from protocols.admission import SuspectBudget, admit
from protocols.auth import Gate, Rejected, Signer
from protocols.datagrams import PARITY_GROUP, Reassembler, split_frame
from protocols.link_config import LinkConfig
from protocols.messages import Message
from protocols.peers import Peer, check_address, check_local_keys
from protocols.receive_faults import HeldCopies, ReceiveFaults
from protocols.transport import Delivery, Ledger, Transport, TransportStats, send_to_each

__all__ = ["UdpTransport", "udp_endpoint"]

#: largest signed frame this transport sends or accepts (reassembled)
DEFAULT_MAX_FRAME = 4 * 2**20


def udp_endpoint(address: str) -> tuple[str, int]:
    """``(host, port)`` of a peers-file address ``tcp://HOST:PORT`` used as a UDP endpoint.

    Raises
    ------
    InputError
        For an ``ipc://`` address or anything :func:`protocols.peers.check_address` refuses.
    """
    try:
        check_address(address, allow_any_port=True)
    except ValueError as err:
        raise InputError(str(err), field="address") from None
    if not address.startswith("tcp://"):
        raise InputError(f"{address!r} has no UDP form (use tcp://HOST:PORT)", field="address")
    host, _, port = address[len("tcp://"):].rpartition(":")
    return host.strip("[]"), int(port)


class UdpTransport(Transport):
    """:class:`protocols.transport.Transport` over UDP datagrams with signed frames.

    Parameters
    ----------
    keys : Mapping[str, SigningKey]
        The local agents (usually one) and their signing keys; each must be in ``peers``.
    peers : Mapping[str, Peer]
        Every agent on the network (the peers file); ``tcp://HOST:PORT`` is used as UDP ``HOST:PORT``.
    rng : numpy.random.Generator, optional
        Root of the per-link fault streams; required when ``faults`` are random.
    faults : LinkConfig
        Receive-side faults of every inbound link (``drop``, ``duplicate``, ``latency``, ``jitter``).
    bind : Mapping[str, str], optional
        Bind a local agent elsewhere than its peers-file address (port 0: a free port).
    mtu : int
        Largest datagram sent (bytes, header included).
    parity_group : int
        Data datagrams per parity datagram of a frame cut into pieces (:mod:`protocols.datagrams`; 0: no
        parity). The default, 4, sends a quarter more bytes for such frames.
    window : int
        Replay window per sender.
    max_frame_bytes : int
        Larger frames are refused (on sending: dropped and counted ``too_large``).
    reassembly : float
        Seconds a frame's pieces wait for the rest.
    max_batch : int
        At most this many datagrams read per :meth:`poll`.
    max_age : float, optional
        Clock tolerance (s) of :class:`protocols.auth.Gate`: refuse (``stale``) frames sent that long
        before this agent started, or that far ahead of its clock (frames of an earlier run); checked
        against ``time.time()``. None (default): no clock check.
    suspect_rate : float
        Signature checks per second shared by every source address that has sent a refused frame
        (:class:`protocols.admission.SuspectBudget`; refusals past it are counted as ``rate``).
    """

    def __init__(self, keys: Mapping[str, SigningKey], peers: Mapping[str, Peer], *,
                 rng: np.random.Generator | None = None, faults: LinkConfig = LinkConfig(),
                 bind: Mapping[str, str] | None = None, mtu: int = 1200, parity_group: int = PARITY_GROUP, window: int = 4096,
                 max_frame_bytes: int = DEFAULT_MAX_FRAME, reassembly: float = 2.0, max_batch: int = 2000,
                 max_age: float | None = None, suspect_rate: float = 200.0):
        if not keys:
            raise InputError("needs at least one local agent", field="keys")
        self._peers = dict(peers)
        check_local_keys(self._peers, keys)
        self._mtu, self._max_frame, self._max_batch = int(mtu), int(max_frame_bytes), int(max_batch)
        self._parity = int(parity_group)
        self._ledger = Ledger()
        self._held = HeldCopies(ReceiveFaults(faults, {}, rng), self._ledger)
        self._max_age = max_age
        self._budget = SuspectBudget(rate=suspect_rate)
        self._frame_id = int.from_bytes(os.urandom(4), "big")  # a restarted sender does not reuse a live id
        self._closed = False
        self._dest: dict[str, tuple] = {}
        self._socks: dict[str, socket.socket] = {}
        self._signers: dict[str, Signer] = {}
        self._gates: dict[str, Gate] = {}
        self._parts: dict[str, Reassembler] = {}
        public = {name: p.public_key for name, p in self._peers.items()}
        try:
            for name, key in keys.items():
                address = (bind or {}).get(name, self._peers[name].address)
                host, port = udp_endpoint(address)
                info = socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)[0]
                sock = socket.socket(info[0], socket.SOCK_DGRAM)
                try:
                    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 * 2**20)
                except OSError:
                    pass  # the kernel's cap applies
                try:
                    sock.bind(info[4])
                except OSError as err:
                    sock.close()
                    raise InputError(f"cannot listen on {address!r}: {err}", field=f"peers.{name}.address") from None
                sock.setblocking(False)
                self._socks[name] = sock
                bound = sock.getsockname()
                shown = f"[{bound[0]}]" if ":" in bound[0] else bound[0]
                self._peers[name] = Peer(name, f"tcp://{shown}:{bound[1]}", self._peers[name].public_key)
                self._signers[name] = Signer(name, key)
                self._gates[name] = Gate(name, public, window, max_age=max_age)
                self._gates[name].own_epoch(self._signers[name].epoch)
                self._parts[name] = Reassembler(max_frame_bytes=self._max_frame, timeout=reassembly)
            for name in self._peers:
                self._resolve(name)
        except BaseException:
            self.close()
            raise

    # ------------------------------------------------------------------ Transport
    @property
    def agents(self) -> tuple[str, ...]:
        return tuple(self._socks)

    @property
    def addresses(self) -> dict[str, str]:
        """Where each local agent listens (a port-0 bind resolved), as ``tcp://HOST:PORT``."""
        return {name: self._peers[name].address for name in self._socks}

    def send(self, message: Message, now: float) -> None:
        """Sign ``message`` once and send its datagrams to its receiver(s); never blocks."""
        if not isinstance(message, Message):
            raise ProtocolError(f"can only send Message objects, got {type(message).__name__}")
        sock = self._socks.get(message.sender)
        if sock is None:
            raise ProtocolError(f"sender {message.sender!r} is not a local agent of this transport")
        self._check_open()
        frame = self._signers[message.sender].seal(message, float(now))
        pieces = split_frame(frame, self._mtu, self._frame_id, self._parity) if len(frame) <= self._max_frame else None
        self._frame_id = (self._frame_id + 1) & 0xFFFFFFFF

        def send_one(b: str) -> str | None:
            dest = self._dest.get(b)
            if pieces is None or dest is None:
                return "too_large" if pieces is None else ("unknown_receiver" if b not in self._peers else "no_address")
            try:
                for piece in pieces:
                    sock.sendto(piece, dest)
            except (BlockingIOError, OSError):  # full socket buffer, or no route: the frame is lost here
                return "queue_full"
            return None

        send_to_each(self._ledger, self._peers, message, len(frame), send_one)

    def poll(self, agent: str, now: float) -> list[Delivery]:
        """Read what has arrived for ``agent`` (never blocks), admit whole frames, return the copies due by ``now``."""
        sock = self._socks.get(agent)
        if sock is None:
            raise ProtocolError(f"agent {agent!r} is not a local agent of this transport")
        self._check_open()
        parts = self._parts[agent]
        for _ in range(self._max_batch):
            try:
                data, source = sock.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                break  # e.g. ICMP port unreachable reported on a connected path: nothing to read
            try:
                frame = parts.add(source, data, now)
            except Rejected as err:
                self._ledger.reject(err.reason)
                continue
            if frame is not None:
                self._admit(agent, frame, source, now)
        lost = parts.expire(now)
        if lost:
            self._ledger.add_reason("incomplete", lost)
        return self._held.due(agent, now)

    def stats(self) -> TransportStats:
        return self._ledger.snapshot()

    def clock_offsets(self, agent: str) -> dict[str, tuple[float, float]]:
        """Per sender, the smallest and largest ``now - sent_at`` that ``agent`` has seen (:meth:`protocols.auth.Gate.clock_offsets`)."""
        return self._gates[agent].clock_offsets()

    def wait(self, timeout: float) -> bool:
        """Block until a datagram is readable on a local socket or ``timeout`` seconds pass."""
        self._check_open()
        ready, _, _ = select.select(list(self._socks.values()), [], [], max(0.0, timeout))
        return bool(ready)

    def next_release(self, agent: str) -> float | None:
        """Arrival time of the earliest copy held back by injected delay for ``agent`` (None if none)."""
        return self._held.next_release(agent)

    def connect(self, addresses: Mapping[str, str]) -> None:
        """Point the peers named in ``addresses`` at new addresses."""
        self._check_open()
        for name, address in addresses.items():
            if name not in self._peers:
                raise InputError(f"agent {name!r} is not in the peers file", field="addresses")
            if name in self._socks:
                raise InputError(f"agent {name!r} is local: its address is where it is bound", field="addresses")
            udp_endpoint(address)
            self._peers[name] = Peer(name, address, self._peers[name].public_key)
            self._resolve(name)

    def close(self, linger: float = 0.0) -> None:
        """Close every socket (datagrams already handed to the kernel leave on their own); safe to call twice."""
        if self._closed:
            return
        self._closed = True
        for sock in self._socks.values():
            sock.close()

    def __enter__(self) -> "UdpTransport":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ internals
    def _resolve(self, name: str) -> None:
        address = self._peers[name].address
        if address.startswith("tcp://") and not address.endswith(":0"):
            host, port = udp_endpoint(address)
            try:
                self._dest[name] = socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)[0][4]
            except socket.gaierror:
                self._dest.pop(name, None)  # counted no_address on send
        else:
            self._dest.pop(name, None)

    def _check_open(self) -> None:
        if self._closed:
            raise ProtocolError("the transport is closed")

    def _admit(self, b: str, frame: bytes, source, now: float) -> None:
        """Check one whole frame from ``source``, cheapest checks first (the envelope, the sender, the
        replay window and the clock before the signature, as :class:`protocols.zmq_transport.ZmqTransport`
        does per connection); count a refusal by reason, else hold it for its arrival time."""
        try:
            env, message = admit(self._gates[b], self._budget, frame, source,
                                 time.time() if self._max_age is not None else None)
        except Rejected as err:
            self._ledger.reject(err.reason)
            return
        self._held.add(message, b, env.sent_at, len(frame), now)  # the link's faults, then held until due
