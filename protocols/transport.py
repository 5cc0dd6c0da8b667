"""The transport interface agents talk through, and the records it hands back.

Agents only ever call :meth:`Transport.send` and :meth:`Transport.poll`; the simulated lossy network
(:class:`protocols.network.SimulatedNetwork`) is one implementation, and a real one (ZeroMQ, ROS 2,
sockets) can replace it without touching the agents. Time is in seconds on a clock the caller owns
(simulation time for the simulated network, wall time for a real transport).

Counting convention (every implementation keeps it): each copy of a message handed to a link is
*sent* once; a duplicate made by the link counts in *duplicated*; each copy ends *delivered* or
*dropped*, or is still *in flight*. So for every agent, link and kind,
``sent + duplicated == delivered + dropped + in_flight``. A broadcast counts once per receiving link.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Mapping

from decentral.errors import ProtocolError
from protocols.messages import CorruptFrame, Message

__all__ = ["Delivery", "Counts", "TransportStats", "Transport", "REJECT_REASONS", "rejection_reason"]

#: drop reasons of frames a receiver refused to decode: ``corrupt`` failed the framing checks
#: (damaged in transit), ``malformed`` was an intact frame whose body is not a valid message
REJECT_REASONS = ("corrupt", "malformed")


def rejection_reason(err: ProtocolError) -> str:
    """The drop reason (one of :data:`REJECT_REASONS`) a transport counts a frame refused with ``err`` under.

    Every transport decodes with :func:`protocols.messages.decode`, catches exactly
    :class:`~decentral.errors.ProtocolError` and counts the frame as dropped for this reason.
    """
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
        ``"unknown_receiver"``, and the rejections ``"corrupt"`` and ``"malformed"``).
    """

    total: Counts
    per_sender: Mapping[str, Counts] = field(default_factory=lambda: MappingProxyType({}))
    per_receiver: Mapping[str, Counts] = field(default_factory=lambda: MappingProxyType({}))
    per_link: Mapping[tuple[str, str], Counts] = field(default_factory=lambda: MappingProxyType({}))
    per_kind: Mapping[str, Counts] = field(default_factory=lambda: MappingProxyType({}))
    drop_reasons: Mapping[str, int] = field(default_factory=lambda: MappingProxyType({}))

    @property
    def rejected(self) -> dict[str, int]:
        """Frames the receivers refused to decode, by reason (:data:`REJECT_REASONS`; zeros included)."""
        return {reason: int(self.drop_reasons.get(reason, 0)) for reason in REJECT_REASONS}

    def as_dict(self) -> dict:
        """JSON-ready form (links keyed ``"sender->receiver"``)."""
        return {
            "total": self.total.as_dict(),
            "per_sender": {k: v.as_dict() for k, v in self.per_sender.items()},
            "per_receiver": {k: v.as_dict() for k, v in self.per_receiver.items()},
            "per_link": {f"{a}->{b}": v.as_dict() for (a, b), v in self.per_link.items()},
            "per_kind": {k: v.as_dict() for k, v in self.per_kind.items()},
            "drop_reasons": dict(self.drop_reasons),
            "rejected": self.rejected,
        }


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
