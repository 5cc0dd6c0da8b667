"""The transport interface agents talk through, and the records it hands back.

Agents only ever call :meth:`Transport.send` and :meth:`Transport.poll`; the simulated lossy network
(:class:`protocols.network.SimulatedNetwork`) is one implementation, and a real one (ZeroMQ, ROS 2,
sockets) can replace it without touching the agents. Time is in seconds on a clock the caller owns
(simulation time for the simulated network, wall time for a real transport).

Counting convention (every implementation keeps it): each copy of a message handed to a link is
*sent* once; a duplicate made by the link counts in *duplicated*; each copy ends *delivered* or
*dropped*, or is still *in flight*. So for every agent, link and kind,
``sent + duplicated == delivered + dropped + in_flight``. A broadcast counts once per receiving link.

A transport whose two ends live in different processes (:class:`protocols.zmq_transport.ZmqTransport`)
keeps the same books split between them: the sending process counts ``sent`` and one copy
``in_flight``, the receiving process counts the copy out of ``in_flight`` (so its own ``in_flight``
goes negative) and into ``delivered``, ``dropped`` or ``duplicated``. Each process's books are half
of each remote link; :func:`merge_stats` adds the books of every process into the balanced whole.
Every frame a receiver refuses is counted by reason in ``rejected``; those refused before the sender
could be trusted (forged, replayed, malformed, unknown sender) are in no link's books.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Callable, Iterable, Mapping

from decentral.errors import ProtocolError
from protocols.messages import CorruptFrame, Message

__all__ = ["Delivery", "Counts", "TransportStats", "Transport", "Ledger", "merge_stats", "rejection_reason"]


def rejection_reason(err: ProtocolError) -> str:
    """The reason a receiver counts a frame refused with ``err`` under (``TransportStats.rejected``).

    An error that carries its own ``reason`` (an envelope check) keeps it; otherwise a frame failing
    the framing checks (:class:`~protocols.messages.CorruptFrame`: damaged in transit) is
    ``"corrupt"`` and an intact frame whose body is not a valid message is ``"malformed"``. Every
    transport decodes with :func:`protocols.messages.decode` and catches exactly
    :class:`~decentral.errors.ProtocolError`.
    """
    reason = getattr(err, "reason", None)
    if isinstance(reason, str) and reason:
        return reason
    return "corrupt" if isinstance(err, CorruptFrame) else "malformed"


@dataclass(frozen=True, slots=True)
class Delivery:
    """One message copy arriving at an agent.

    Attributes
    ----------
    message : Message
        The decoded message (a broadcast keeps ``receiver == BROADCAST``).
    receiver : str
        The agent it was delivered to.
    sent_at, delivered_at : float
        Send and arrival times (s).
    size_bytes : int
        Wire size of the copy.
    duplicate : bool
        Whether this copy is a duplicate made by the link.
    """

    message: Message
    receiver: str
    sent_at: float
    delivered_at: float
    size_bytes: int
    duplicate: bool = False

    @property
    def sender(self) -> str:
        return self.message.sender

    @property
    def latency(self) -> float:
        return self.delivered_at - self.sent_at


@dataclass(frozen=True, slots=True)
class Counts:
    """Message and byte counters for one key (an agent, a link, a kind, or the total)."""

    sent: int = 0
    delivered: int = 0
    dropped: int = 0
    duplicated: int = 0
    in_flight: int = 0
    bytes_sent: int = 0
    bytes_delivered: int = 0
    bytes_dropped: int = 0

    def balanced(self) -> bool:
        """Whether ``sent + duplicated == delivered + dropped + in_flight``."""
        return self.sent + self.duplicated == self.delivered + self.dropped + self.in_flight

    def as_dict(self) -> dict[str, int]:
        return {name: getattr(self, name) for name in self.__slots__}


@dataclass(frozen=True)
class TransportStats:
    """A frozen snapshot of a transport's counters.

    Attributes
    ----------
    total : Counts
        Over all traffic.
    per_sender, per_receiver : Mapping[str, Counts]
        Traffic an agent sent / traffic addressed to an agent.
    per_link : Mapping[tuple[str, str], Counts]
        Per directed link ``(sender, receiver)``.
    per_kind : Mapping[str, Counts]
        Per message ``KIND``.
    drop_reasons : Mapping[str, int]
        Dropped copies by cause (``"loss"``, ``"partition"``, ``"sender_down"``, ``"receiver_down"``,
        ``"unknown_receiver"``, ``"queue_full"``, and the simulated network's decode failures).
    rejected : Mapping[str, int]
        Inbound frames the receiving side refused, by reason (reasons that occurred only). The
        simulated network refuses frames that fail to decode (``"corrupt"``: damaged in transit;
        ``"malformed"``: intact but not a valid message, see :func:`rejection_reason`); they are
        also dropped copies of their link. The real transport refuses frames it cannot trust
        (``"bad_signature"``, ``"replay"``, ``"unknown_sender"``, ``"malformed"``); those are in no
        link's books, since their sender and kind are unknown.
    """

    total: Counts
    per_sender: Mapping[str, Counts] = field(default_factory=lambda: MappingProxyType({}))
    per_receiver: Mapping[str, Counts] = field(default_factory=lambda: MappingProxyType({}))
    per_link: Mapping[tuple[str, str], Counts] = field(default_factory=lambda: MappingProxyType({}))
    per_kind: Mapping[str, Counts] = field(default_factory=lambda: MappingProxyType({}))
    drop_reasons: Mapping[str, int] = field(default_factory=lambda: MappingProxyType({}))
    rejected: Mapping[str, int] = field(default_factory=lambda: MappingProxyType({}))

    def as_dict(self) -> dict:
        """JSON-ready form (links keyed ``"sender->receiver"``)."""
        return {
            "total": self.total.as_dict(),
            "per_sender": {k: v.as_dict() for k, v in self.per_sender.items()},
            "per_receiver": {k: v.as_dict() for k, v in self.per_receiver.items()},
            "per_link": {f"{a}->{b}": v.as_dict() for (a, b), v in self.per_link.items()},
            "per_kind": {k: v.as_dict() for k, v in self.per_kind.items()},
            "drop_reasons": dict(self.drop_reasons),
            "rejected": dict(self.rejected),
        }

    @classmethod
    def from_dict(cls, data: Mapping) -> "TransportStats":
        """The inverse of :meth:`as_dict` (e.g. to merge the stats each agent process printed as JSON).

        Raises ``KeyError``/``TypeError``/``ValueError`` on a dict that is not an :meth:`as_dict` result.
        """
        def table(name: str, key=lambda k: k) -> Mapping:
            return MappingProxyType({key(k): Counts(**v) for k, v in data.get(name, {}).items()})

        return cls(
            total=Counts(**data["total"]),
            per_sender=table("per_sender"),
            per_receiver=table("per_receiver"),
            per_link=table("per_link", lambda k: tuple(k.split("->", 1))),
            per_kind=table("per_kind"),
            drop_reasons=MappingProxyType({str(k): int(v) for k, v in data.get("drop_reasons", {}).items()}),
            rejected=MappingProxyType({str(k): int(v) for k, v in data.get("rejected", {}).items()}),
        )


class Transport(abc.ABC):
    """What an agent needs from a network: send, poll its inbox, and counters.

    Implementations must be safe to drive from one thread in simulated or wall time, never block
    in :meth:`send`, and keep the counting convention of this module.
    """

    @property
    @abc.abstractmethod
    def agents(self) -> tuple[str, ...]:
        """Names of the agents attached to this transport."""

    @abc.abstractmethod
    def send(self, message: Message, now: float) -> None:
        """Hand ``message`` to the network at time ``now``; a broadcast goes to every other agent.

        Never raises for a lost message: loss is only visible to the receiving side (as absence).
        """

    @abc.abstractmethod
    def poll(self, agent: str, now: float) -> list[Delivery]:
        """Return, in arrival order, every copy for ``agent`` that has arrived by ``now`` (and forget them)."""

    @abc.abstractmethod
    def stats(self) -> TransportStats:
        """Return a frozen snapshot of the counters."""

    def deliver(self, now: float) -> dict[str, list[Delivery]]:
        """Poll every agent at ``now``: agent -> its arrivals (agents with none are included, empty)."""
        return {agent: self.poll(agent, now) for agent in self.agents}


_FIELDS = Counts.__slots__
_IDX = {name: i for i, name in enumerate(_FIELDS)}
_SCOPES = ("sender", "receiver", "link", "kind")


class Ledger:
    """The books of a transport: counters per total, sender, receiver, link and kind, plus drop and
    rejection reasons, snapshotted as :class:`TransportStats`.

    A copy's rows are named by :meth:`keys` (compute them once per copy on a hot path and pass them
    to :meth:`bump` and :meth:`drop`); :meth:`count` does both in one call.
    """

    def __init__(self) -> None:
        self._rows: dict[tuple[str, object], list[int]] = {}
        self._reasons: dict[str, int] = {}
        self._rejected: dict[str, int] = {}

    @staticmethod
    def keys(a: str, b: str, kind: str) -> tuple:
        """The rows a copy from ``a`` to ``b`` of ``kind`` counts in: total, sender, receiver, link, kind."""
        return (("total", None), ("sender", a), ("receiver", b), ("link", (a, b)), ("kind", kind))

    def bump(self, keys: tuple, *changes: tuple[str, int]) -> None:
        """Add each ``(counter name, amount)`` of ``changes`` to every row of ``keys``."""
        rows = self._rows
        for key in keys:
            row = rows.get(key)
            if row is None:
                row = rows[key] = [0] * len(_FIELDS)
            for name, n in changes:
                row[_IDX[name]] += n

    def count(self, a: str, b: str, kind: str, *changes: tuple[str, int]) -> None:
        """:meth:`bump` the rows of one copy from ``a`` to ``b`` of ``kind``."""
        self.bump(self.keys(a, b, kind), *changes)

    def drop(self, keys: tuple, size: int, reason: str, *changes: tuple[str, int]) -> None:
        """Count one dropped copy of ``size`` bytes (and any further ``changes``) under ``reason``."""
        self.bump(keys, ("dropped", 1), ("bytes_dropped", size), *changes)
        self.add_reason(reason)

    def add_reason(self, reason: str, n: int = 1) -> None:
        """Count ``n`` more drops under ``reason`` (their counters are bumped by the caller)."""
        self._reasons[reason] = self._reasons.get(reason, 0) + n

    def reject(self, reason: str, n: int = 1) -> None:
        """Count ``n`` refused inbound frames under ``reason``."""
        self._rejected[reason] = self._rejected.get(reason, 0) + n

    def snapshot(self, extra_rows: dict | None = None) -> TransportStats:
        """A frozen :class:`TransportStats` of the books (plus ``extra_rows``: row key -> counts, added)."""
        rows = {key: list(vals) for key, vals in self._rows.items()}
        for key, vals in (extra_rows or {}).items():
            row = rows.setdefault(key, [0] * len(_FIELDS))
            for f, v in enumerate(vals):
                row[f] += int(v)
        return _stats_from_rows(rows, self._reasons, self._rejected)


def _stats_from_rows(rows: dict, reasons: Mapping[str, int], rejected: Mapping[str, int]) -> TransportStats:
    def scope(name: str) -> Mapping:
        picked = sorted(((key, vals) for (k, key), vals in rows.items() if k == name), key=lambda kv: str(kv[0]))
        return MappingProxyType({key: Counts(*vals) for key, vals in picked})

    return TransportStats(
        total=Counts(*rows.get(("total", None), [0] * len(_FIELDS))),
        per_sender=scope("sender"),
        per_receiver=scope("receiver"),
        per_link=scope("link"),
        per_kind=scope("kind"),
        drop_reasons=MappingProxyType(dict(sorted(reasons.items()))),
        rejected=MappingProxyType(dict(sorted(rejected.items()))),
    )


def merge_stats(parts: "list[TransportStats] | tuple[TransportStats, ...]") -> TransportStats:
    """The sum of several transports' books (e.g. of every agent process): each counter added per key."""
    rows: dict[tuple[str, object], list[int]] = {}
    reasons: dict[str, int] = {}
    rejected: dict[str, int] = {}

    def add(key, counts: Counts) -> None:
        row = rows.setdefault(key, [0] * len(_FIELDS))
        for f, name in enumerate(_FIELDS):
            row[f] += getattr(counts, name)

    for part in parts:
        add(("total", None), part.total)
        for name, table in zip(_SCOPES, (part.per_sender, part.per_receiver, part.per_link, part.per_kind)):
            for key, counts in table.items():
                add((name, key), counts)
        for book, src in ((reasons, part.drop_reasons), (rejected, part.rejected)):
            for reason, n in src.items():
                book[reason] = book.get(reason, 0) + n
    return _stats_from_rows(rows, reasons, rejected)


def send_to_each(ledger: Ledger, peers: Iterable[str], message: Message, size: int,
                 send_one: Callable[[str], str | None]) -> None:
    """Send one sealed frame of ``message`` (``size`` bytes) to its receiver, or to every other peer of
    ``peers`` for a broadcast, with ``send_one(receiver)`` (``None``: sent; else the reason it was dropped,
    e.g. ``"queue_full"``), and count each copy in ``ledger``: the send half the socket transports share."""
    a, kind = message.sender, message.KIND
    receivers = [b for b in peers if b != a] if message.is_broadcast else [message.receiver]
    for b in receivers:
        keys = ledger.keys(a, b, kind)
        reason = send_one(b)
        if reason is None:
            ledger.bump(keys, ("sent", 1), ("bytes_sent", size), ("in_flight", 1))
        else:
            ledger.drop(keys, size, reason, ("sent", 1), ("bytes_sent", size))
