"""The batched path of :class:`protocols.network.SimulatedNetwork`: many copies of one kind per call.

:meth:`~BatchedPath.send_many` hands many copies of one message kind (agent indices, wire sizes) to
the network in one call and :meth:`~BatchedPath.poll_many` returns the arrived ones as arrays
(:class:`BatchDelivery`); the caller keeps the payloads. Each copy meets the fate the per-message
path would give it: the same refusals, the same six draws per copy from its link's stream in batch
order, the same bandwidth queue, loss, duplication, jitter and counters. Two differences, neither
observable in outcomes or counts: nothing is encoded (the caller passes the exact wire size), so a
corrupted copy is dropped as ``"corrupt"`` at arrival without a CRC check (a one-byte flip always
fails CRC-32); and a link whose behaviour has no randomness (no drop, corruption, duplication or
jitter) makes no draws, since they could change nothing. Batched copies are only returned by
:meth:`~BatchedPath.poll_many`, per-message copies only by the network's ``poll``; after a batched
send, time must not go back (both paths raise).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from decentral.errors import ProtocolError
from protocols.link_config import NetworkConfig
from protocols.transport import Counts

__all__ = ["BatchDelivery", "BatchedPath"]

_FIELDS = Counts.__slots__
_IDX = {name: i for i, name in enumerate(_FIELDS)}


@dataclass(frozen=True)
class BatchDelivery:
    """Copies sent with :meth:`BatchedPath.send_many` that arrived, as parallel arrays in arrival order
    (ties by send order), shape (m,) each.

    Attributes
    ----------
    batch : ndarray of int
        The id :meth:`~BatchedPath.send_many` returned for the call that sent the copy.
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


class BatchedPath:
    """The batched send and poll of :class:`protocols.network.SimulatedNetwork`, with their counters.

    A mixin: it uses the network's ``config``, ``is_down``, ``link_rng``, ``_ledger``, ``_free_at``
    and ``_seq`` (shared with the per-message path, so both draw from the same link streams, queue on
    the same bandwidth and number copies in one sequence), and keeps its copies in flight and its
    counters as arrays, merged into the network's ``stats()`` by :meth:`_merge_batched`.
    """

    config: NetworkConfig

    def _init_batched(self, config: NetworkConfig) -> None:
        """Empty batched state: nothing in flight, every counter zero."""
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
        drop_p = self._frame_loss(s, r, size, drop_p)
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

    def _frame_loss(self, s: np.ndarray, r: np.ndarray, size: np.ndarray, drop_p: np.ndarray) -> np.ndarray:
        """Per-copy loss: ``drop_p`` itself, or from it per datagram on links with an ``mtu`` (:meth:`LinkConfig.frame_loss`)."""
        base, links = self.config.link, self.config.links
        if not base.mtu and not any(cfg.mtu for cfg in links.values()):
            return drop_p
        agents = self.config.agents
        out = drop_p.copy()
        for q, (a, b) in enumerate(zip(s.tolist(), r.tolist())):
            out[q] = links.get((agents[a], agents[b]), base).frame_loss(int(size[q]))
        return out

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
