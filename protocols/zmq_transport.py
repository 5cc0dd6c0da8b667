"""A real transport over ZeroMQ sockets, with signed frames and receive-side fault injection.

Socket pattern: every agent binds one PULL socket at its address (from the peers file) and the
transport holds one PUSH socket per peer, connected to that peer's address. PUSH/PULL has no
late-joiner loss (unlike PUB/SUB): a PUSH socket queues frames for a peer that is not up yet (or is
restarting) and hands them over when the connection comes up. Each queue holds at most ``hwm``
frames; a send never blocks: a frame that finds its queue full is dropped at once and counted
(``drop_reasons["queue_full"]``), never dropped silently. Every socket closes with linger 0, so no
process waits on exit for frames nobody will read.

Every frame is a signed envelope (:mod:`protocols.auth`); a receiver refuses forged, replayed,
malformed and unknown-sender frames, counts them by reason in ``stats().rejected`` and goes on.

The cost of what arrives is bounded, cheapest refusal first: libzmq refuses a frame over
``max_frame_bytes`` from its header, before reading it (it drops the connection; nothing is
allocated, and libzmq does not say why, so such frames are not counted); each inbound connection
queues at most ``rcvhwm`` frames (past that, TCP pushes back on the sender); what can be refused
without a signature check is (:meth:`protocols.auth.Gate.screen`); connections that sent a refused
frame share a budget of signature checks (:class:`protocols.admission.SuspectBudget`, refusals past
it counted as ``rate``); :meth:`poll` spends at most ``poll_budget`` seconds reading, and
:meth:`wait` uses the caller's idle time to read and check what arrives, waking the caller only
for frames that pass (a flood of refused frames never wakes it). Frames still queued when the
transport closes are counted as ``unread``. ZeroMQ fair-queues the inbound connections, so a
flood on one connection delays the others' frames by at most its share of each read.
Loss, duplication and delay can be injected *at the receiving side*, after a frame is admitted
(:mod:`protocols.receive_faults`): the ``k``-th frame admitted on a link meets the fate the ``k``-th
copy sent on that link meets in a :class:`~protocols.network.SimulatedNetwork` of the same seed.

Counting follows :mod:`protocols.transport`: the sending process counts ``sent``/``bytes_sent``
(the envelope's size: framing included) and one copy in flight per receiving link; the receiving
process moves each admitted copy out of flight into ``delivered`` or ``dropped`` (and counts
``duplicated`` copies). :func:`protocols.transport.merge_stats` over every process's stats gives the
balanced books.

How an agent process uses it (``now`` is the runtime's wall clock, seconds)::

    import time
    import numpy as np
    from protocols.messages import BROADCAST, Heartbeat
    from protocols.peers import load_peers, load_private_key
    from protocols.zmq_transport import ZmqTransport

    name, key = load_private_key("keys/A0.key.json")
    peers = load_peers("keys/peers.json")
    with ZmqTransport({name: key}, peers, rng=np.random.default_rng(seed)) as net:
        while running:
            net.send(Heartbeat(sender=name, receiver=BROADCAST, round=k), time.time())
            net.wait(0.01)                      # until a frame is readable, at most 10 ms
            for d in net.poll(name, time.time()):
                handle(d.message)               # authenticated and decoded
        print(net.stats().as_dict())

Several agents can share one transport (one process hosting several agents, e.g. in tests:
:func:`open_loopback`); their frames still go through the sockets.
"""

from __future__ import annotations

import math
import time
from typing import Mapping

import numpy as np
import zmq
from nacl.signing import SigningKey

from decentral.errors import InputError, ProtocolError
from protocols.admission import SuspectBudget, admit
from protocols.auth import Gate, Opened, Rejected, Signer, new_private_key, public_key_bytes
from protocols.messages import Message
from protocols.link_config import LinkConfig
from protocols.peers import Peer, check_address, check_local_keys
from protocols.receive_faults import HeldCopies, ReceiveFaults
from protocols.transport import Delivery, Ledger, Transport, TransportStats, send_to_each
from protocols.zmq_drops import DropWatch

__all__ = ["ZmqTransport", "open_loopback"]

#: frames above this size are refused by the socket itself (libzmq drops the connection that sent it); the
#: largest frame of the protocol, a window's whole bundle, is ~1 MB at 512 assemblies (the assembly limit)
DEFAULT_MAX_FRAME = 4 * 2**20
#: frames each inbound connection may queue before TCP pushes back on its sender
DEFAULT_RCVHWM = 64
#: seconds of reading and checking one poll may spend (the rest waits for the next poll, or a wait)
DEFAULT_POLL_BUDGET = 0.005
#: frames counted as unread at close, at most (the rest are discarded uncounted)
_MAX_UNREAD = 100_000


class _Endpoint:
    """One local agent: its bound inbound socket, its signer, its gate, and the frames admitted since its last poll."""

    def __init__(self, name: str, socket: zmq.Socket, signer: Signer, gate: Gate):
        self.name = name
        self.socket = socket
        self.drops = DropWatch(socket)  # connections libzmq dropped on a frame over MAXMSGSIZE
        self.signer = signer
        self.gate = gate
        self.admitted: list[tuple[Opened, Message, int]] = []  # checked, waiting for a poll to apply faults
        self.address = socket.getsockopt_string(zmq.LAST_ENDPOINT)


class ZmqTransport(Transport):
    """:class:`protocols.transport.Transport` over ZeroMQ PUSH/PULL sockets with signed frames.

    Parameters
    ----------
    keys : Mapping[str, SigningKey]
        The local agents (usually one) and their signing keys; each must be in ``peers`` with the
        matching public key.
    peers : Mapping[str, Peer]
        Every agent on the network (the peers file, :func:`protocols.peers.load_peers`).
    rng : numpy.random.Generator, optional
        Draws the root of the per-link fault streams (once); required when ``faults`` or ``links``
        are random. Give every process the same seed.
    faults : LinkConfig
        Receive-side faults of every inbound link (default: none).
    links : Mapping[tuple[str, str], LinkConfig]
        Per inbound link ``(sender, receiver)`` overrides of ``faults``.
    bind : Mapping[str, str], optional
        Bind a local agent somewhere else than its peers-file address (``tcp://127.0.0.1:0`` binds a
        free port; :attr:`addresses` tells which).
    hwm : int
        Frames each outbound queue holds (ZeroMQ send high-water mark).
    window : int
        Replay window per sender (:class:`protocols.auth.ReplayWindow`).
    max_frame_bytes : int
        Larger inbound frames are refused by the socket (default 4 MiB).
    max_batch : int
        At most this many frames are read per :meth:`poll`.
    rcvhwm : int
        Frames each inbound connection queues (ZeroMQ receive high-water mark).
    poll_budget : float
        Seconds of reading and checking per :meth:`poll`.
    suspect_rate : float
        Signature checks per second shared by the connections that sent refused frames.
    max_age : float, optional
        Clock tolerance (s) of :class:`protocols.auth.Gate`: refuse, as ``stale``, frames sent more
        than this long before the transport was made or this far ahead of the receiver's clock.
        Needs ``now`` to be ``time.time()`` in :meth:`send` and :meth:`poll`. None (default): no
        clock check.
    """

    def __init__(
        self,
        keys: Mapping[str, SigningKey],
        peers: Mapping[str, Peer],
        *,
        rng: np.random.Generator | None = None,
        faults: LinkConfig = LinkConfig(),
        links: Mapping[tuple[str, str], LinkConfig] | None = None,
        bind: Mapping[str, str] | None = None,
        hwm: int = 2000,
        window: int = 1024,
        max_frame_bytes: int = DEFAULT_MAX_FRAME,
        max_batch: int = 1000,
        rcvhwm: int = DEFAULT_RCVHWM,
        poll_budget: float = DEFAULT_POLL_BUDGET,
        suspect_rate: float = 200.0,
        max_age: float | None = None,
    ):
        if not keys:
            raise InputError("needs at least one local agent", field="keys")
        self._peers = dict(peers)
        check_local_keys(self._peers, keys)
        stray = set(bind or {}) - set(keys)
        if stray:
            raise InputError(f"bind names agents that are not local: {sorted(stray)}", field="bind")
        faults = ReceiveFaults(faults, links or {}, rng)
        self._hwm, self._max_batch = int(hwm), int(max_batch)
        self._poll_budget = float(poll_budget)
        self._budget = SuspectBudget(rate=suspect_rate)
        self._admitted = 0
        self._ledger = Ledger()
        self._held = HeldCopies(faults, self._ledger)
        self._closed = False
        self._context = zmq.Context()
        self._sockets: list[zmq.Socket] = []  # every socket made, so close() closes even a half-built one
        self._out: dict[str, zmq.Socket] = {}
        self._local: dict[str, _Endpoint] = {}
        public = {name: p.public_key for name, p in self._peers.items()}
        try:
            for name, key in keys.items():
                address = (bind or {}).get(name, self._peers[name].address)
                socket = self._socket(zmq.PULL)
                socket.setsockopt(zmq.RCVHWM, int(rcvhwm))
                socket.setsockopt(zmq.MAXMSGSIZE, int(max_frame_bytes))
                try:
                    check_address(address, allow_any_port=True)
                    socket.bind(address[:-2] + ":*" if address.endswith(":0") else address)
                except (zmq.ZMQError, ValueError) as err:
                    raise InputError(f"cannot listen on {address!r}: {err}", field=f"peers.{name}.address") from None
                self._local[name] = _Endpoint(name, socket, Signer(name, key),
                                              Gate(name, public, window, max_age=max_age))
                self._local[name].gate.own_epoch(self._local[name].signer.epoch)
                self._peers[name] = Peer(name, self._local[name].address, self._peers[name].public_key)
            for name in self._peers:
                self._connect(name)
            self._poller = zmq.Poller()
            for ep in self._local.values():
                self._poller.register(ep.socket, zmq.POLLIN)
        except BaseException:
            self.close()
            raise

    # ------------------------------------------------------------------ Transport
    @property
    def agents(self) -> tuple[str, ...]:
        """The local agents (the ones :meth:`poll` serves)."""
        return tuple(self._local)

    @property
    def peers(self) -> tuple[str, ...]:
        """Every agent on the network, local or not."""
        return tuple(self._peers)

    @property
    def addresses(self) -> dict[str, str]:
        """Where each local agent actually listens (a port-0 bind resolved)."""
        return {name: ep.address for name, ep in self._local.items()}

    def send(self, message: Message, now: float) -> None:
        """Sign ``message`` once and queue it to its receiver (a broadcast: to every other peer); never blocks."""
        if not isinstance(message, Message):
            raise ProtocolError(f"can only send Message objects, got {type(message).__name__}")
        ep = self._local.get(message.sender)
        if ep is None:
            raise ProtocolError(f"sender {message.sender!r} is not a local agent of this transport")
        self._check_open()
        frame = ep.signer.seal(message, float(now))

        def send_one(b: str) -> str | None:
            socket = self._out.get(b)
            if socket is None:
                return "unknown_receiver" if b not in self._peers else "no_address"
            try:
                socket.send(frame, zmq.NOBLOCK)
            except zmq.Again:
                return "queue_full"
            return None

        send_to_each(self._ledger, self._peers, message, len(frame), send_one)

    def poll(self, agent: str, now: float) -> list[Delivery]:
        """Read what has arrived for ``agent`` (never blocks), admit it, and return the copies due by ``now``."""
        ep = self._local.get(agent)
        if ep is None:
            raise ProtocolError(f"agent {agent!r} is not a local agent of this transport")
        self._check_open()
        self._read(ep, time.perf_counter() + self._poll_budget, float(now), self._max_batch)
        for env, message, size in ep.admitted:  # the link's faults, then held until due
            self._held.add(message, ep.name, env.sent_at, size, float(now))
        ep.admitted.clear()
        return self._held.due(agent, now)

    def stats(self) -> TransportStats:
        self._count_oversize()
        return self._ledger.snapshot()

    # ------------------------------------------------------------------ runtime helpers
    def wait(self, timeout: float) -> bool:
        """Block until a frame that passes every check has arrived for a local agent, or ``timeout`` seconds pass.

        While it waits it reads and checks what arrives (refused frames are counted and never wake
        it; admitted ones wait for the next :meth:`poll`). Returns whether a frame was admitted
        during this call (frames admitted earlier and not yet polled do not make it return at once).
        Copies held back by injected delay do not wake it: a runtime that injects delay also wakes
        at :meth:`next_release`. The clock check (``max_age``) reads ``time.time()`` here.
        """
        self._check_open()
        deadline = time.perf_counter() + max(0.0, timeout)
        before = self._admitted
        while True:
            if self._admitted > before:
                return True
            left = deadline - time.perf_counter()
            if left <= 0 or not self._poller.poll(max(0, int(math.ceil(left * 1000)))):
                return self._admitted > before
            for ep in self._local.values():
                self._read(ep, deadline, time.time(), None)

    def clock_offsets(self, agent: str) -> dict[str, tuple[float, float]]:
        """Per sender, the smallest and largest ``now - sent_at`` that ``agent`` has seen (:meth:`protocols.auth.Gate.clock_offsets`)."""
        return self._local[agent].gate.clock_offsets()

    def next_release(self, agent: str) -> float | None:
        """Arrival time of the earliest copy held back by injected delay for ``agent`` (None if none)."""
        return self._held.next_release(agent)

    def connect(self, addresses: Mapping[str, str]) -> None:
        """Point the peers named in ``addresses`` at new addresses (frames already queued are discarded)."""
        self._check_open()
        for name, address in addresses.items():
            if name not in self._peers:
                raise InputError(f"agent {name!r} is not in the peers file", field="addresses")
            try:
                check_address(address)
            except ValueError as err:
                raise InputError(str(err), field=f"addresses.{name}") from None
            if name in self._local:
                raise InputError(f"agent {name!r} is local: its address is where it is bound", field="addresses")
            self._peers[name] = Peer(name, address, self._peers[name].public_key)
            old = self._out.pop(name, None)
            if old is not None:
                old.close(linger=0)
                self._sockets.remove(old)
            self._connect(name)

    def close(self, linger: float = 0.0) -> None:
        """Close every socket and return within about ``linger`` seconds; safe to call twice.

        Frames still queued to a peer get up to ``linger`` seconds to leave (default 0: discarded
        at once, so a process never hangs on a peer that is gone). Closing never blocks longer.
        """
        if self._closed:
            return
        self._count_unread()
        for ep in self._local.values():
            ep.drops.stop()
        self._count_oversize()
        self._closed = True
        deadline = time.monotonic() + max(0.0, linger)
        outbound = set(self._out.values())
        for socket in self._sockets:
            socket.close(linger=int(1000 * max(0.0, deadline - time.monotonic())) if socket in outbound else 0)
        self._context.term()

    def __enter__(self) -> "ZmqTransport":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ internals
    def _socket(self, kind: int) -> zmq.Socket:
        socket = self._context.socket(kind)
        self._sockets.append(socket)
        socket.setsockopt(zmq.LINGER, 0)
        socket.setsockopt(zmq.IPV6, 1)  # tcp://[::1]:PORT and IPv4 addresses alike
        return socket

    def _connect(self, name: str) -> None:
        """Open the PUSH socket to peer ``name`` if its address is known (port 0 = not yet)."""
        address = self._peers[name].address
        if address.endswith(":0"):
            return
        socket = self._socket(zmq.PUSH)
        socket.setsockopt(zmq.SNDHWM, self._hwm)
        socket.connect(address)
        self._out[name] = socket

    def _check_open(self) -> None:
        if self._closed:
            raise ProtocolError("the transport is closed")

    def _read(self, ep: _Endpoint, deadline: float, now: float, most: int | None) -> None:
        """Read and check frames for ``ep`` until none is queued, ``deadline`` (perf_counter) or ``most`` frames."""
        n = 0
        while most is None or n < most:
            if n and time.perf_counter() > deadline:
                break
            try:
                frame = ep.socket.recv(zmq.NOBLOCK, copy=False)
            except zmq.Again:
                break
            n += 1
            try:
                conn = frame.get(zmq.SRCFD)  # which connection it came on (a file descriptor)
            except zmq.ZMQError:
                conn = -1  # its connection is gone already: such frames are judged together
            self._admit(ep, frame.bytes, conn, now)
        self._count_oversize()

    def _admit(self, ep: _Endpoint, frame: bytes, conn: int, now: float) -> None:
        """Check one inbound frame from connection ``conn``, cheapest checks first; count a refusal by
        reason, else queue it for the next poll."""
        try:
            env, message = admit(ep.gate, self._budget, frame, conn, now)
        except Rejected as err:
            self._ledger.reject(err.reason)
            return
        self._admitted += 1
        ep.admitted.append((env, message, len(frame)))

    def _count_unread(self) -> None:
        """Count what is still queued on the inbound sockets as ``unread`` (at most ``_MAX_UNREAD``, 0.5 s)."""
        deadline = time.perf_counter() + 0.5
        n = 0
        for ep in self._local.values():
            n += len(ep.admitted)
            ep.admitted.clear()
            while n < _MAX_UNREAD and time.perf_counter() < deadline:
                try:
                    ep.socket.recv(zmq.NOBLOCK, copy=False)
                except (zmq.Again, zmq.ZMQError):
                    break
                n += 1
        if n:
            self._ledger.reject("unread", n)

    def _count_oversize(self) -> None:
        """Count the connections libzmq dropped on a frame over the size limit as ``oversize`` refusals."""
        n = sum(ep.drops.take() for ep in self._local.values())
        if n:
            self._ledger.reject("oversize", n)


def open_loopback(
    names: list[str] | tuple[str, ...], seed: int | None = None, **kwargs
) -> tuple[dict[str, ZmqTransport], dict[str, Peer]]:
    """One transport per agent on 127.0.0.1 free ports, keys made fresh, every transport connected to all.

    Each transport gets its own ``np.random.default_rng(seed)`` (as separate processes given the
    same ``--seed`` would); ``kwargs`` go to every :class:`ZmqTransport`. Returns (name ->
    transport, the peers table with the bound addresses). The caller closes the transports.
    """
    keys = {name: new_private_key() for name in names}
    peers = {name: Peer(name, "tcp://127.0.0.1:0", public_key_bytes(key)) for name, key in keys.items()}
    transports: dict[str, ZmqTransport] = {}
    try:
        for name in names:
            rng = None if seed is None else np.random.default_rng(seed)
            transports[name] = ZmqTransport({name: keys[name]}, peers, rng=rng, **kwargs)
        table = {name: Peer(name, transports[name].addresses[name], peers[name].public_key) for name in names}
        for name, t in transports.items():
            t.connect({other: p.address for other, p in table.items() if other != name})
    except BaseException:
        for t in transports.values():
            t.close()
        raise
    return transports, table
