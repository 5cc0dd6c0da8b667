"""A seeded, deterministic simulated lossy network implementing :class:`protocols.transport.Transport`.

Every message really goes over the wire: :meth:`SimulatedNetwork.send` encodes it
(:meth:`Message.to_bytes`), the link may corrupt the frame, and the receiver decodes it on
:meth:`~SimulatedNetwork.poll` (a corrupted frame fails its CRC and is counted as dropped, reason
``"corrupt"``). Per directed link ``(a, b)`` a copy sent at time ``t``:

1. is refused if ``a`` is down at ``t`` (``"sender_down"``) or a partition active at ``t`` separates
   ``a`` from ``b`` (``"partition"``);
2. queues behind earlier copies on the link if the link has a bandwidth cap ``W`` bytes/s: it starts
   at ``s = max(t, free_at)`` and occupies the link for ``size / W`` seconds;
3. is lost with probability ``drop`` (``"loss"``), else corrupted with probability ``corrupt``;
4. arrives at ``s + size / W + latency + U(0, jitter)`` -- reordering falls out of the jitter;
5. is duplicated with probability ``duplicate`` (the copy gets its own jitter);
6. is dropped at arrival if ``b`` is down then (``"receiver_down"``).

Each link draws from its own random stream, ``SeedSequence(root, spawn_key=(crc32(a), crc32(b)))``,
with a fixed number of draws per copy, so adding an agent or a link never changes another link's loss
pattern. Time is in seconds; :meth:`SimulatedNetwork.time_of_round` maps synchronous rounds to times.
"""

from __future__ import annotations

import functools
import heapq
import math
import zlib
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Mapping

import numpy as np

from decentral.errors import InputError, ProtocolError
from protocols.messages import BROADCAST, Message, decode
from protocols.transport import Counts, Delivery, Transport, TransportStats

__all__ = ["LinkConfig", "Partition", "Crash", "NetworkConfig", "SimulatedNetwork"]

#: a broadcast is one frame delivered to many receivers; messages are immutable, so decoding the same
#: bytes once and sharing the result is exact (a corrupted copy has other bytes and fails on its own)
_decode_frame = functools.lru_cache(maxsize=2048)(decode)


def _prob(value: float, name: str) -> None:
    if not (isinstance(value, (int, float)) and 0.0 <= value <= 1.0):
        raise InputError(f"must be a probability in [0, 1], got {value!r}", field=name)


@dataclass(frozen=True)
class LinkConfig:
    """Behaviour of one directed link.

    Attributes
    ----------
    drop : float
        Probability that a copy is lost.
    latency : float
        Fixed propagation delay (s).
    jitter : float
        Extra delay drawn uniformly from ``[0, jitter]`` (s) per copy.
    duplicate : float
        Probability that a delivered copy arrives twice.
    corrupt : float
        Probability that a copy arrives with one byte flipped (rejected by the receiver's CRC check).
    bandwidth : float
        Cap in bytes per second (``inf`` = no cap); copies queue behind each other.
    """

    drop: float = 0.0
    latency: float = 0.0
    jitter: float = 0.0
    duplicate: float = 0.0
    corrupt: float = 0.0
    bandwidth: float = math.inf

    def __post_init__(self) -> None:
        for name in ("drop", "duplicate", "corrupt"):
            _prob(getattr(self, name), name)
        for name in ("latency", "jitter"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise InputError(f"must be a finite non-negative time, got {v!r}", field=name)
        if not (isinstance(self.bandwidth, (int, float)) and self.bandwidth > 0):
            raise InputError(f"must be positive bytes per second, got {self.bandwidth!r}", field="bandwidth")


@dataclass(frozen=True)
class Partition:
    """During ``[t0, t1)`` agents in different groups cannot reach each other.

    Agents listed in no group form one more group together, so ``groups=({"A", "B"},)`` cuts
    ``{A, B}`` off from everyone else.
    """

    t0: float
    t1: float
    groups: tuple[frozenset[str], ...]

    def __post_init__(self) -> None:
        if not (self.t0 < self.t1):
            raise InputError("needs t0 < t1", field="partition")
        groups = tuple(frozenset(g) for g in self.groups)
        seen: set[str] = set()
        for g in groups:
            if seen & g:
                raise InputError("an agent is in two groups", field="partition.groups")
            seen |= g
        object.__setattr__(self, "groups", groups)

    def _group(self, agent: str) -> int:
        for i, g in enumerate(self.groups):
            if agent in g:
                return i
        return -1

    def separates(self, a: str, b: str, t: float) -> bool:
        """Whether ``a`` and ``b`` are cut off from each other at time ``t``."""
        return self.t0 <= t < self.t1 and self._group(a) != self._group(b)


@dataclass(frozen=True)
class Crash:
    """``agent`` is down (neither sends nor receives) during ``[t0, t1)``; ``t1 = inf`` never returns."""

    agent: str
    t0: float
    t1: float = math.inf

    def __post_init__(self) -> None:
        if not (self.t0 < self.t1):
            raise InputError("needs t0 < t1", field="crash")

    def down(self, agent: str, t: float) -> bool:
        return agent == self.agent and self.t0 <= t < self.t1


@dataclass(frozen=True)
class NetworkConfig:
    """Configuration of a :class:`SimulatedNetwork`.

    Attributes
    ----------
    agents : tuple of str
        Every agent attached to the network (unique names).
    link : LinkConfig
        Default behaviour of every directed link.
    links : Mapping[tuple[str, str], LinkConfig]
        Per directed link ``(sender, receiver)`` overrides.
    partitions : tuple of Partition
    crashes : tuple of Crash
    round_period : float
        Seconds per synchronous round (see :meth:`SimulatedNetwork.time_of_round`).
    """

    agents: tuple[str, ...]
    link: LinkConfig = field(default_factory=LinkConfig)
    links: Mapping[tuple[str, str], LinkConfig] = field(default_factory=dict)
    partitions: tuple[Partition, ...] = ()
    crashes: tuple[Crash, ...] = ()
    round_period: float = 0.1

    def __post_init__(self) -> None:
        agents = tuple(self.agents)
        if len(set(agents)) != len(agents) or not all(isinstance(a, str) and a and a != BROADCAST for a in agents):
            raise InputError("agent names must be unique, non-empty and not the broadcast marker", field="agents")
        object.__setattr__(self, "agents", agents)
        for (a, b) in self.links:
            if a not in agents or b not in agents:
                raise InputError(f"link {a!r}->{b!r} names an unknown agent", field="links")
        object.__setattr__(self, "links", MappingProxyType(dict(self.links)))
        object.__setattr__(self, "partitions", tuple(self.partitions))
        object.__setattr__(self, "crashes", tuple(self.crashes))
        if not (self.round_period > 0 and math.isfinite(self.round_period)):
            raise InputError("must be a positive finite time", field="round_period")

    def link_config(self, a: str, b: str) -> LinkConfig:
        """Behaviour of the directed link ``a -> b``."""
        return self.links.get((a, b), self.link)


_FIELDS = Counts.__slots__
_IDX = {name: i for i, name in enumerate(_FIELDS)}


@dataclass(order=True)
class _InFlight:
    arrival: float
    seq: int
    frame: bytes = field(compare=False)
    sent_at: float = field(compare=False)
    sender: str = field(compare=False)
    kind: str = field(compare=False)
    duplicate: bool = field(compare=False)


class SimulatedNetwork(Transport):
    """Seeded, deterministic lossy network (see the module docstring for the model).

    Parameters
    ----------
    config : NetworkConfig
    rng : numpy.random.Generator
        Only used once, to draw the root entropy of the per-link streams.
    """

    def __init__(self, config: NetworkConfig, rng: np.random.Generator):
        self.config = config
        self._root = [int(x) for x in rng.integers(0, 2**32, size=4, dtype=np.uint64)]
        self._rngs: dict[tuple[str, str], np.random.Generator] = {}
        self._free_at: dict[tuple[str, str], float] = {}
        self._queues: dict[str, list[_InFlight]] = {a: [] for a in config.agents}
        self._seq = 0
        self._counters: dict[tuple[str, object], list[int]] = {}
        self._reasons: dict[str, int] = {}

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
            seq = np.random.SeedSequence(
                self._root, spawn_key=(zlib.crc32(a.encode("utf-8")), zlib.crc32(b.encode("utf-8")))
            )
            gen = self._rngs[key] = np.random.default_rng(seq)
        return gen

    def send(self, message: Message, now: float) -> None:
        if not isinstance(message, Message):
            raise ProtocolError(f"can only send Message objects, got {type(message).__name__}")
        a = message.sender
        if a not in self._queues:
            raise ProtocolError(f"sender {a!r} is not attached to this network")
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
            keys = self._keys(item.sender, agent, item.kind)
            size = len(item.frame)
            self._bump(keys, ("in_flight", -1))
            if self.is_down(agent, item.arrival):
                self._drop(keys, size, "receiver_down")
                continue
            try:
                message = _decode_frame(item.frame)
            except ProtocolError:
                self._drop(keys, size, "corrupt")
                continue
            self._bump(keys, ("delivered", 1), ("bytes_delivered", size))
            out.append(Delivery(message, agent, item.sent_at, item.arrival, size, item.duplicate))
        return out

    def pending(self, agent: str) -> int:
        """Copies still in flight to ``agent``."""
        return len(self._queues[agent])

    def stats(self) -> TransportStats:
        def snap(kind: str) -> Mapping:
            return MappingProxyType(
                {key: Counts(*vals) for (k, key), vals in sorted(self._counters.items(), key=_sort_key) if k == kind}
            )

        total = self._counters.get(("total", None), [0] * len(_FIELDS))
        return TransportStats(
            total=Counts(*total),
            per_sender=snap("sender"),
            per_receiver=snap("receiver"),
            per_link=snap("link"),
            per_kind=snap("kind"),
            drop_reasons=MappingProxyType(dict(sorted(self._reasons.items()))),
        )

    # ------------------------------------------------------------------ internals
    def _keys(self, a: str, b: str, kind: str) -> tuple:
        return (("total", None), ("sender", a), ("receiver", b), ("link", (a, b)), ("kind", kind))

    def _bump(self, keys: tuple, *changes: tuple[str, int]) -> None:
        """Add each ``(counter name, amount)`` of ``changes`` to the rows of every key."""
        counters = self._counters
        width = len(_FIELDS)
        for key in keys:
            row = counters.get(key)
            if row is None:
                row = counters[key] = [0] * width
            for name, n in changes:
                row[_IDX[name]] += n

    def _drop(self, keys: tuple, size: int, reason: str) -> None:
        self._bump(keys, ("dropped", 1), ("bytes_dropped", size))
        self._reasons[reason] = self._reasons.get(reason, 0) + 1

    def _send_copy(self, a: str, b: str, kind: str, frame: bytes, now: float) -> None:
        size = len(frame)
        keys = self._keys(a, b, kind)
        self._bump(keys, ("sent", 1), ("bytes_sent", size))
        if b not in self._queues:
            self._drop(keys, size, "unknown_receiver")
            return
        if self.is_down(a, now):
            self._drop(keys, size, "sender_down")
            return
        if any(p.separates(a, b, now) for p in self.config.partitions):
            self._drop(keys, size, "partition")
            return
        cfg = self.config.link_config(a, b)
        # fixed number of draws per copy keeps each link's pattern independent of everything else
        u_drop, u_corrupt, u_dup, u_jit, u_jit2, u_pos = self.link_rng(a, b).random(6)
        start = max(now, self._free_at.get((a, b), -math.inf))
        tx = size / cfg.bandwidth if math.isfinite(cfg.bandwidth) else 0.0
        self._free_at[(a, b)] = start + tx
        if u_drop < cfg.drop:
            self._drop(keys, size, "loss")
            return
        if u_corrupt < cfg.corrupt:
            pos = min(int(u_pos * size), size - 1)
            frame = frame[:pos] + bytes([frame[pos] ^ 0xFF]) + frame[pos + 1 :]
        arrival = start + tx + cfg.latency + u_jit * cfg.jitter
        self._enqueue(b, _InFlight(arrival, self._next_seq(), frame, now, a, kind, False), keys)
        if u_dup < cfg.duplicate:
            self._bump(keys, ("duplicated", 1))
            arrival2 = start + tx + cfg.latency + u_jit2 * cfg.jitter
            self._enqueue(b, _InFlight(arrival2, self._next_seq(), frame, now, a, kind, True), keys)

    def _enqueue(self, b: str, item: _InFlight, keys: tuple) -> None:
        self._bump(keys, ("in_flight", 1))
        heapq.heappush(self._queues[b], item)

    def _next_seq(self) -> int:
        self._seq += 1
        return self._seq


def _sort_key(item: tuple) -> tuple:
    (kind, key), _ = item
    return (kind, str(key))
