"""A seeded, deterministic simulated lossy network implementing :class:`protocols.transport.Transport`.

Every message really goes over the wire: :meth:`SimulatedNetwork.send` encodes it
(:meth:`Message.to_bytes`), the link (:class:`protocols.link_config.LinkConfig`, drawing from its own
stream, :func:`protocols.link_config.link_stream`, six draws per copy) may corrupt the frame, and the
receiver decodes it on :meth:`~SimulatedNetwork.poll` (a corrupted frame fails its CRC and is counted
as dropped, reason ``"corrupt"``; an intact frame whose body is not a valid message, reason
``"malformed"``; both are also refused: ``stats().rejected``). Per directed link ``(a, b)`` a copy
sent at time ``t``: (1) is refused if ``a`` is down at ``t`` (``"sender_down"``) or a partition
active at ``t`` separates ``a`` from ``b`` (``"partition"``); (2) queues behind earlier copies on the
link if the link has a bandwidth cap ``W`` bytes/s: it starts at ``s = max(t, free_at)`` and occupies
the link for ``size / W`` seconds; (3) is lost with probability ``drop`` (``"loss"``; with the link's
``mtu``, ``drop`` is per datagram and larger frames are lost more often), else corrupted
with probability ``corrupt``; (4) arrives at ``s + size / W + latency + U(0, jitter)`` (reordering
falls out of the jitter); (5) is duplicated with probability ``duplicate`` (the copy gets its own
jitter); (6) is dropped at arrival if ``b`` is down then (``"receiver_down"``). Time is in seconds;
:meth:`SimulatedNetwork.time_of_round` maps synchronous rounds to times. The batched path
(``send_many``, ``poll_many``) is in :mod:`protocols.network_batch`; the configuration names are
re-exported here.
"""

from __future__ import annotations

import functools
import heapq
import math
from dataclasses import dataclass, field

import numpy as np

from decentral.errors import ProtocolError
from protocols.link_config import Crash, LinkConfig, NetworkConfig, Partition, link_root, link_stream
from protocols.messages import Message, decode
from protocols.network_batch import BatchDelivery, BatchedPath
from protocols.transport import Delivery, Ledger, Transport, TransportStats, rejection_reason

__all__ = ["link_root", "link_stream", "LinkConfig", "Partition", "Crash", "NetworkConfig", "BatchDelivery",
           "SimulatedNetwork"]

#: a broadcast is one frame delivered to many receivers; messages are immutable, so decoding the same
#: bytes once and sharing the result is exact (a corrupted copy has other bytes and fails on its own)
_decode_frame = functools.lru_cache(maxsize=2048)(decode)


@dataclass(order=True)
class _InFlight:
    arrival: float
    seq: int
    frame: bytes = field(compare=False)
    sent_at: float = field(compare=False)
    sender: str = field(compare=False)
    kind: str = field(compare=False)
    duplicate: bool = field(compare=False)


class SimulatedNetwork(BatchedPath, Transport):
    """Seeded, deterministic lossy network (see the module docstring for the model).

    Parameters
    ----------
    config : NetworkConfig
    rng : numpy.random.Generator
        Only used once, to draw the root entropy of the per-link streams.
    """

    def __init__(self, config: NetworkConfig, rng: np.random.Generator):
        self.config = config
        self._root = link_root(rng)
        self._rngs: dict[tuple[str, str], np.random.Generator] = {}
        self._free_at: dict[tuple[str, str], float] = {}
        self._queues: dict[str, list[_InFlight]] = {a: [] for a in config.agents}
        self._seq = 0
        self._ledger = Ledger()
        self._init_batched(config)

    # ------------------------------------------------------------------ Transport
    @property
    def agents(self) -> tuple[str, ...]:
        return self.config.agents

    def time_of_round(self, k: int) -> float:
        """Start time (s) of synchronous round ``k``: ``k * round_period``."""
        return k * self.config.round_period

    def is_down(self, agent: str, t: float) -> bool:
        """Whether ``agent`` is crashed at time ``t``."""
        return any(c.down(agent, t) for c in self.config.crashes)

    def reachable(self, a: str, b: str, t: float) -> bool:
        """Whether no partition separates ``a`` and ``b`` at ``t`` and both are up."""
        return not (
            self.is_down(a, t) or self.is_down(b, t) or any(p.separates(a, b, t) for p in self.config.partitions)
        )

    def link_rng(self, a: str, b: str) -> np.random.Generator:
        """The random stream of the directed link ``a -> b`` (keyed by the names, not by order)."""
        key = (a, b)
        gen = self._rngs.get(key)
        if gen is None:
            gen = self._rngs[key] = link_stream(self._root, a, b)
        return gen

    def send(self, message: Message, now: float) -> None:
        if not isinstance(message, Message):
            raise ProtocolError(f"can only send Message objects, got {type(message).__name__}")
        a = message.sender
        if a not in self._queues:
            raise ProtocolError(f"sender {a!r} is not attached to this network")
        if now < self._batch_now:
            raise ProtocolError(f"time went back to {now} after a batched send at {self._batch_now}")
        frame = message.to_bytes()
        receivers = [b for b in self.config.agents if b != a] if message.is_broadcast else [message.receiver]
        for b in receivers:
            self._send_copy(a, b, message.KIND, frame, float(now))

    def poll(self, agent: str, now: float) -> list[Delivery]:
        if agent not in self._queues:
            raise ProtocolError(f"agent {agent!r} is not attached to this network")
        queue = self._queues[agent]
        out: list[Delivery] = []
        while queue and queue[0].arrival <= now:
            item = heapq.heappop(queue)
            keys = Ledger.keys(item.sender, agent, item.kind)
            size = len(item.frame)
            self._ledger.bump(keys, ("in_flight", -1))
            if self.is_down(agent, item.arrival):
                self._ledger.drop(keys, size, "receiver_down")
                continue
            try:
                message = _decode_frame(item.frame)
            except ProtocolError as err:
                reason = rejection_reason(err)
                self._ledger.drop(keys, size, reason)
                self._ledger.reject(reason)
                continue
            self._ledger.bump(keys, ("delivered", 1), ("bytes_delivered", size))
            out.append(Delivery(message, agent, item.sent_at, item.arrival, size, item.duplicate))
        return out

    def pending(self, agent: str) -> int:
        """Copies still in flight to ``agent`` (per-message and batched)."""
        k = self._index(agent)
        return len(self._queues[agent]) + sum(int(np.count_nonzero(f["receiver"] == k)) for f in self._flight)

    def stats(self) -> TransportStats:
        rows: dict = {}
        if self._batches:
            self._merge_batched(rows)
        return self._ledger.snapshot(rows)

    def _index(self, agent: str) -> int:
        if agent not in self._queues:
            raise ProtocolError(f"agent {agent!r} is not attached to this network")
        return self._agent_index[agent]

    # ------------------------------------------------------------------ internals
    def _send_copy(self, a: str, b: str, kind: str, frame: bytes, now: float) -> None:
        size = len(frame)
        keys = Ledger.keys(a, b, kind)
        self._ledger.bump(keys, ("sent", 1), ("bytes_sent", size))
        if b not in self._queues:
            self._ledger.drop(keys, size, "unknown_receiver")
            return
        if self.is_down(a, now):
            self._ledger.drop(keys, size, "sender_down")
            return
        if any(p.separates(a, b, now) for p in self.config.partitions):
            self._ledger.drop(keys, size, "partition")
            return
        cfg = self.config.link_config(a, b)
        # fixed number of draws per copy keeps each link's pattern independent of everything else
        u_drop, u_corrupt, u_dup, u_jit, u_jit2, u_pos = self.link_rng(a, b).random(6)
        start = max(now, self._free_at.get((a, b), -math.inf))
        tx = size / cfg.bandwidth if math.isfinite(cfg.bandwidth) else 0.0
        self._free_at[(a, b)] = start + tx
        if u_drop < cfg.frame_loss(size):
            self._ledger.drop(keys, size, "loss")
            return
        if u_corrupt < cfg.corrupt:
            pos = min(int(u_pos * size), size - 1)
            frame = frame[:pos] + bytes([frame[pos] ^ 0xFF]) + frame[pos + 1 :]
        arrival = start + tx + cfg.latency + u_jit * cfg.jitter
        self._enqueue(b, _InFlight(arrival, self._next_seq(), frame, now, a, kind, False), keys)
        if u_dup < cfg.duplicate:
            self._ledger.bump(keys, ("duplicated", 1))
            arrival2 = start + tx + cfg.latency + u_jit2 * cfg.jitter
            self._enqueue(b, _InFlight(arrival2, self._next_seq(), frame, now, a, kind, True), keys)

    def _enqueue(self, b: str, item: _InFlight, keys: tuple) -> None:
        self._ledger.bump(keys, ("in_flight", 1))
        heapq.heappush(self._queues[b], item)

    def _next_seq(self) -> int:
        self._seq += 1
        return self._seq
