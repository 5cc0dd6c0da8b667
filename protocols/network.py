"""A seeded, deterministic simulated lossy network implementing :class:`protocols.transport.Transport`.

Every message really goes over the wire: :meth:`SimulatedNetwork.send` encodes it
(:meth:`Message.to_bytes`), the link may corrupt the frame, and the receiver decodes it on
:meth:`~SimulatedNetwork.poll` (a corrupted frame fails its CRC and is counted as dropped, reason
``"corrupt"``, and refused: ``stats().rejected``). Per directed link ``(a, b)`` a copy sent at time ``t``:

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

**Batched path.** :meth:`SimulatedNetwork.send_many` hands many copies of one message kind (agent
indices, wire sizes) to the network in one call and :meth:`SimulatedNetwork.poll_many` returns the
arrived ones as arrays (:class:`BatchDelivery`); the caller keeps the payloads. Each copy meets the
fate the per-message path would give it: the same refusals, the same six draws per copy from its
link's stream in batch order, the same bandwidth queue, loss, duplication, jitter and counters. Two
differences, neither observable in outcomes or counts: nothing is encoded (the caller passes the
exact wire size), so a corrupted copy is dropped as ``"corrupt"`` at arrival without a CRC check (a
one-byte flip always fails CRC-32); and a link whose behaviour has no randomness (no drop,
corruption, duplication or jitter) makes no draws, since they could change nothing. Batched copies
are only returned by :meth:`~SimulatedNetwork.poll_many`, per-message copies only by
:meth:`~SimulatedNetwork.poll`; after a batched send, time must not go back (both paths raise).
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
from protocols.transport import Counts, Delivery, Ledger, Transport, TransportStats

__all__ = ["link_root", "link_stream", "LinkConfig", "Partition", "Crash", "NetworkConfig", "BatchDelivery",
           "SimulatedNetwork"]

#: a broadcast is one frame delivered to many receivers; messages are immutable, so decoding the same
#: bytes once and sharing the result is exact (a corrupted copy has other bytes and fails on its own)
_decode_frame = functools.lru_cache(maxsize=2048)(decode)


def link_root(rng: np.random.Generator) -> list[int]:
    """Root entropy of the per-link streams, drawn once from ``rng`` (128 bits)."""
    return [int(x) for x in rng.integers(0, 2**32, size=4, dtype=np.uint64)]


def link_stream(root: list[int], a: str, b: str) -> np.random.Generator:
    """The random stream of the directed link ``a -> b``: ``SeedSequence(root, spawn_key=(crc32(a), crc32(b)))``.

    Keyed by the names, so adding an agent or a link never changes another link's stream, and two
    processes given the same root draw the same stream for the same link.
    """
    seq = np.random.SeedSequence(root, spawn_key=(zlib.crc32(a.encode("utf-8")), zlib.crc32(b.encode("utf-8"))))
    return np.random.default_rng(seq)


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


@dataclass(frozen=True)
class BatchDelivery:
    """Copies sent with :meth:`SimulatedNetwork.send_many` that arrived, as parallel arrays in arrival
    order (ties by send order), shape (m,) each.

    Attributes
    ----------
    batch : ndarray of int
        The id :meth:`~SimulatedNetwork.send_many` returned for the call that sent the copy.
    index : ndarray of int
        Row of the copy in that call (the caller's payload row).
    sender, receiver : ndarray of int
        Agent indices into ``config.agents``.
    sent_at, arrival : ndarray of float
        Send and arrival times (s).
    size : ndarray of int
        Wire size in bytes.
    duplicate : ndarray of bool
        Whether the copy is a duplicate made by the link.
    """

    batch: np.ndarray
    index: np.ndarray
    sender: np.ndarray
    receiver: np.ndarray
    sent_at: np.ndarray
    arrival: np.ndarray
    size: np.ndarray
    duplicate: np.ndarray

    def __len__(self) -> int:
        return int(self.index.size)


_FLIGHT_FIELDS = ("arrival", "seq", "batch", "index", "sender", "receiver", "kind", "size", "sent_at",
                  "duplicate", "corrupt")


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
        self._root = link_root(rng)
        self._rngs: dict[tuple[str, str], np.random.Generator] = {}
        self._free_at: dict[tuple[str, str], float] = {}
        self._queues: dict[str, list[_InFlight]] = {a: [] for a in config.agents}
        self._seq = 0
        self._ledger = Ledger()
        # batched path: copies in flight as arrays, counters as arrays (merged in stats())
        n, width = len(config.agents), len(_FIELDS)
        self._n = n
        self._agent_index = {a: k for k, a in enumerate(config.agents)}
        self._flight: list[dict[str, np.ndarray]] = []
        self._batches = 0
        self._batch_now = -math.inf
        self._b_sender = np.zeros((n, width), dtype=np.int64)
        self._b_receiver = np.zeros((n, width), dtype=np.int64)
        self._b_total = np.zeros(width, dtype=np.int64)
        self._b_kinds: list[str] = []
        self._b_kind = np.zeros((0, width), dtype=np.int64)
        self._b_link_codes = np.zeros(0, dtype=np.int64)  # sender * n + receiver, sorted
        self._b_link = np.zeros((0, width), dtype=np.int64)

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
            except ProtocolError:
                self._ledger.drop(keys, size, "corrupt")
                self._ledger.reject("corrupt")
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

    # ------------------------------------------------------------------ batched path
    def send_many(self, kind: str, senders, receivers, sizes, now: float) -> int:
        """Hand copies of one message kind to the network at time ``now`` in one call.

        Parameters
        ----------
        kind : str
            The message ``KIND`` (counted per kind like the per-message path).
        senders, receivers : array_like of int, shape (m,)
            Agent indices into ``config.agents``; copy ``k`` goes over the link
            ``senders[k] -> receivers[k]``. Copies sharing a link are sent in batch order.
        sizes : int or array_like of int, shape (m,)
            Wire size of each copy in bytes (what ``Message.size_bytes`` would be).
        now : float
            Send time (s); not earlier than any earlier send.

        Returns
        -------
        int
            The batch id that :class:`BatchDelivery` rows carry.
        """
        s = np.asarray(senders, dtype=np.int64).ravel()
        r = np.asarray(receivers, dtype=np.int64).ravel()
        m, n = s.size, self._n
        if r.size != m:
            raise ProtocolError(f"send_many: {m} senders but {r.size} receivers")
        if m and (s.min() < 0 or s.max() >= n or r.min() < 0 or r.max() >= n):
            raise ProtocolError("send_many: agent index out of range")
        size = np.broadcast_to(np.asarray(sizes, dtype=np.int64), (m,)).copy()
        now = float(now)
        if now < self._batch_now:
            raise ProtocolError(f"send_many: time went back from {self._batch_now} to {now}")
        self._batch_now = now
        batch = self._batches
        self._batches += 1
        if m == 0:
            return batch
        kid = self._kind_id(kind)
        self._bump_many(s, r, kid, ("sent", None), ("bytes_sent", size))
        alive = np.ones(m, dtype=bool)
        if self.config.crashes:
            down = np.array([self.is_down(a, now) for a in self.config.agents])
            refused = down[s]
            self._drop_many(s[refused], r[refused], kid, size[refused], "sender_down")
            alive &= ~refused
        if self.config.partitions:
            refused = np.zeros(m, dtype=bool)
            for p in self.config.partitions:
                if p.t0 <= now < p.t1:
                    grp = np.array([p._group(a) for a in self.config.agents])
                    refused |= grp[s] != grp[r]
            refused &= alive
            self._drop_many(s[refused], r[refused], kid, size[refused], "partition")
            alive &= ~refused
        idx = np.flatnonzero(alive)
        s, r, size = s[idx], r[idx], size[idx]
        k = idx.size
        params = self._link_params(s, r)  # drop, corrupt, duplicate, latency, jitter, bandwidth (k,) each
        drop_p, corrupt_p, dup_p, latency, jitter, bandwidth = params
        u = np.zeros((k, 6))
        random = (drop_p > 0) | (corrupt_p > 0) | (dup_p > 0) | (jitter > 0)
        if random.any():
            # the per-message path's six draws per copy, from each link's own stream, in batch order
            sel = np.flatnonzero(random)
            codes = s[sel] * n + r[sel]
            order = np.argsort(codes, kind="stable")
            uniq, starts = np.unique(codes[order], return_index=True)
            ends = np.append(starts[1:], order.size)
            agents = self.config.agents
            for code, a0, a1 in zip(uniq.tolist(), starts.tolist(), ends.tolist()):
                rows = sel[order[a0:a1]]
                u[rows] = self.link_rng(agents[code // n], agents[code % n]).random((rows.size, 6))
        start = np.full(k, now)
        tx = np.zeros(k)
        capped = np.isfinite(bandwidth)
        if capped.any():
            agents = self.config.agents
            for q in np.flatnonzero(capped).tolist():  # a link queue is sequential
                key = (agents[s[q]], agents[r[q]])
                start[q] = max(now, self._free_at.get(key, -math.inf))
                tx[q] = size[q] / bandwidth[q]
                self._free_at[key] = start[q] + tx[q]
        lost = u[:, 0] < drop_p
        self._drop_many(s[lost], r[lost], kid, size[lost], "loss")
        keep = ~lost
        corrupt = u[:, 1] < corrupt_p
        dup = keep & (u[:, 2] < dup_p)
        base = start + tx + latency
        # sequence numbers as the per-message path assigns them: a copy, then its duplicate
        n_seq = keep.astype(np.int64) + dup
        last = self._seq + np.cumsum(n_seq)
        seq1 = last - n_seq + 1
        self._seq = int(last[-1]) if k else self._seq
        kk, dd = np.flatnonzero(keep), np.flatnonzero(dup)
        both = np.concatenate([kk, dd])
        flight = {
            "arrival": np.concatenate([base[kk] + u[kk, 3] * jitter[kk], base[dd] + u[dd, 4] * jitter[dd]]),
            "seq": np.concatenate([seq1[kk], seq1[dd] + 1]),
            "batch": np.full(both.size, batch, dtype=np.int64),
            "index": idx[both],
            "sender": s[both],
            "receiver": r[both],
            "kind": np.full(both.size, kid, dtype=np.int64),
            "size": size[both],
            "sent_at": np.full(both.size, now),
            "duplicate": np.concatenate([np.zeros(kk.size, dtype=bool), np.ones(dd.size, dtype=bool)]),
            "corrupt": corrupt[both],
        }
        if dd.size:
            self._bump_many(s[dd], r[dd], kid, ("duplicated", None))
        if both.size:
            self._bump_many(flight["sender"], flight["receiver"], kid, ("in_flight", None))
            self._flight.append(flight)
        return batch

    def poll_many(self, now: float) -> BatchDelivery:
        """Every batched copy (to any agent) that has arrived by ``now``, in arrival order (and forget them).

        A copy to an agent that is down at its arrival is dropped (``"receiver_down"``), a corrupted
        one fails its check (``"corrupt"``); neither is returned.
        """
        arrived, still = [], []
        for f in self._flight:
            due = f["arrival"] <= now
            if due.all():
                arrived.append(f)
            elif due.any():
                arrived.append({key: v[due] for key, v in f.items()})
                still.append({key: v[~due] for key, v in f.items()})
            else:
                still.append(f)
        self._flight = still
        if not arrived:
            z = np.zeros(0, dtype=np.int64)
            return BatchDelivery(z, z, z, z, np.zeros(0), np.zeros(0), z, np.zeros(0, dtype=bool))
        c = {key: np.concatenate([f[key] for f in arrived]) for key in _FLIGHT_FIELDS}
        order = np.lexsort((c["seq"], c["arrival"]))
        c = {key: v[order] for key, v in c.items()}
        s, r, kind, size = c["sender"], c["receiver"], c["kind"], c["size"]
        ok = ~c["corrupt"]
        down = np.zeros(s.size, dtype=bool)
        for crash in self.config.crashes:
            if crash.agent in self.config.agents:
                k = self.config.agents.index(crash.agent)
                down |= (r == k) & (crash.t0 <= c["arrival"]) & (c["arrival"] < crash.t1)
        for kid in np.unique(kind).tolist():
            mk = kind == kid
            self._bump_many(s[mk], r[mk], kid, ("in_flight", -1))
            for mask, reason in ((mk & down, "receiver_down"), (mk & ~down & ~ok, "corrupt")):
                self._drop_many(s[mask], r[mask], kid, size[mask], reason)
            if (n_corrupt := int(np.count_nonzero(mk & ~down & ~ok))):
                self._ledger.reject("corrupt", n_corrupt)
            good = mk & ~down & ok
            self._bump_many(s[good], r[good], kid, ("delivered", None), ("bytes_delivered", size[good]))
        good = ~down & ok
        return BatchDelivery(c["batch"][good], c["index"][good], s[good], r[good], c["sent_at"][good],
                             c["arrival"][good], size[good], c["duplicate"][good])

    def _index(self, agent: str) -> int:
        if agent not in self._queues:
            raise ProtocolError(f"agent {agent!r} is not attached to this network")
        return self._agent_index[agent]

    def _kind_id(self, kind: str) -> int:
        if kind not in self._b_kinds:
            self._b_kinds.append(kind)
            self._b_kind = np.vstack([self._b_kind, np.zeros((1, len(_FIELDS)), dtype=np.int64)])
        return self._b_kinds.index(kind)

    def _link_params(self, s: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, ...]:
        """Per-copy link behaviour (drop, corrupt, duplicate, latency, jitter, bandwidth), shape (k,) each."""
        names = ("drop", "corrupt", "duplicate", "latency", "jitter", "bandwidth")
        base = self.config.link
        out = [np.full(s.size, float(getattr(base, name))) for name in names]
        if self.config.links:
            agents = self.config.agents
            for q, (a, b) in enumerate(zip(s.tolist(), r.tolist())):
                cfg = self.config.links.get((agents[a], agents[b]))
                if cfg is not None:
                    for arr, name in zip(out, names):
                        arr[q] = float(getattr(cfg, name))
        return tuple(out)

    def _drop_many(self, s: np.ndarray, r: np.ndarray, kid: int, size: np.ndarray, reason: str) -> None:
        if s.size:
            self._bump_many(s, r, kid, ("dropped", None), ("bytes_dropped", size))
            self._ledger.add_reason(reason, int(s.size))

    def _bump_many(self, s: np.ndarray, r: np.ndarray, kid: int, *changes) -> None:
        """Add each ``(counter name, amounts or None = 1 per copy, or a scalar)`` to every key of the copies."""
        m = s.size
        if m == 0:
            return
        n = self._n
        rows = self._link_rows(s * n + r)
        for name, v in changes:
            f = _IDX[name]
            if v is None or np.isscalar(v):
                w = None if v is None or v == 1 else np.full(m, float(v))
                total = m if v is None else int(v) * m
            else:
                w = np.asarray(v, dtype=np.float64)
                total = int(np.asarray(v).sum())
            for table, key in ((self._b_sender, s), (self._b_receiver, r), (self._b_link, rows)):
                col = table[:, f]
                if 8 * m < table.shape[0]:  # few copies: touch only their rows
                    np.add.at(col, key, 1 if w is None else w.astype(np.int64))
                else:
                    add = np.bincount(key, weights=w, minlength=table.shape[0])
                    col += add.astype(np.int64) if w is not None else add
                table[:, f] = col
            self._b_kind[kid, f] += total
            self._b_total[f] += total

    def _link_rows(self, codes: np.ndarray) -> np.ndarray:
        """Rows of the batched per-link table for link codes ``sender * n + receiver`` (registering new ones)."""
        known = self._b_link_codes
        pos = np.searchsorted(known, codes)
        hit = pos < known.size
        hit[hit] = known[pos[hit]] == codes[hit]
        if not hit.all():
            merged = np.union1d(known, codes[~hit])
            table = np.zeros((merged.size, len(_FIELDS)), dtype=np.int64)
            table[np.searchsorted(merged, known)] = self._b_link
            self._b_link_codes, self._b_link = merged, table
            pos = np.searchsorted(merged, codes)
        return pos

    def _merge_batched(self, rows: dict) -> None:
        """Add the batched counters to the per-message ``rows`` (key -> list of counts)."""
        agents, n, width = self.config.agents, self._n, len(_FIELDS)

        def add(key, vec) -> None:
            row = rows.setdefault(key, [0] * width)
            for f, v in enumerate(vec.tolist()):
                row[f] += v

        add(("total", None), self._b_total)
        for k in np.flatnonzero(self._b_sender.any(1)).tolist():
            add(("sender", agents[k]), self._b_sender[k])
        for k in np.flatnonzero(self._b_receiver.any(1)).tolist():
            add(("receiver", agents[k]), self._b_receiver[k])
        for kid, kind in enumerate(self._b_kinds):
            add(("kind", kind), self._b_kind[kid])
        for code, vec in zip(self._b_link_codes.tolist(), self._b_link):
            add(("link", (agents[code // n], agents[code % n])), vec)

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
        if u_drop < cfg.drop:
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
