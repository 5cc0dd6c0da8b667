"""Round-synchronous gather/broadcast: the send and receive halves of a neighbour exchange.

A consensus protocol (ADMM, averaging, ...) runs in rounds. In round ``k`` each agent broadcasts its
value to its neighbours (send half, :meth:`RoundGather.outgoing`), routes the messages it receives to
:meth:`RoundGather.receive` (receive half), and at the round's deadline calls
:meth:`RoundGather.close`, which returns a :class:`GatherResult`: the value of each neighbour for
round ``k`` if it arrived (*fresh*), else the newest older value received with its age in rounds
(*stale*), and the neighbours never heard from (*missing*). Lost or late messages are therefore an
explicit failure the protocol handles (reuse stale values, lower their weight, or wait), never a hang.
The numerical reduction over the gathered values is a pure function in :mod:`decentral`.

:func:`exchange_round` drives one round for a set of agents over a :class:`Transport` in simulated
time: everyone sends at ``t_k = k * period``, and the inboxes are read at ``t_k + deadline``.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType
from typing import Callable, Generic, Iterable, Mapping, TypeVar

from decentral.errors import ProtocolError
from protocols.messages import BROADCAST, Message
from protocols.transport import Delivery, Transport

__all__ = ["GatherResult", "RoundGather", "exchange_round"]

M = TypeVar("M", bound=Message)


@dataclass(frozen=True)
class GatherResult(Generic[M]):
    """What an agent knows about its neighbours at the deadline of round ``round``.

    Attributes
    ----------
    round : int
    fresh : Mapping[str, Message]
        Neighbours whose round-``round`` message arrived in time.
    stale : Mapping[str, Message]
        Neighbours whose round-``round`` message did not arrive but an older one did: the newest one.
    ages : Mapping[str, int]
        For every neighbour in ``fresh`` (age 0) or ``stale``: ``round`` minus the round of its message.
    missing : tuple of str
        Expected neighbours with no message at all for this round (fresh or stale are not missing).
    late : tuple of str
        Expected neighbours whose round-``round`` message did not arrive by the deadline.
    """

    round: int
    fresh: Mapping[str, M]
    stale: Mapping[str, M]
    ages: Mapping[str, int]
    missing: tuple[str, ...]
    late: tuple[str, ...]

    @property
    def values(self) -> dict[str, M]:
        """Fresh and stale messages together, by neighbour."""
        return {**self.stale, **self.fresh}

    @property
    def complete(self) -> bool:
        """Whether every expected neighbour's round-``round`` message arrived."""
        return not self.late


class RoundGather(Generic[M]):
    """Collect one message kind from a fixed set of neighbours, round by round.

    Parameters
    ----------
    owner : str
        The agent running this gather.
    neighbours : iterable of str
        Agents it expects a message from every round.
    kind : type
        The :class:`Message` subclass carrying the values; other kinds are ignored by :meth:`receive`.
    accept : callable, optional
        Extra filter on messages of that kind (e.g. same ADMM window); rejected ones are ignored.
    """

    def __init__(
        self,
        owner: str,
        neighbours: Iterable[str],
        kind: type[M],
        accept: Callable[[M], bool] | None = None,
    ):
        self.owner = owner
        self.neighbours = tuple(sorted(set(neighbours) - {owner}))
        self.kind = kind
        self.accept = accept
        self._by_round: dict[int, dict[str, M]] = {}
        self._past: dict[str, M] = {}  # newest message per neighbour from a closed round
        self._closed = -(2**63)

    # ------------------------------------------------------------------ send half
    def outgoing(self, make: Callable[[str], M], *, broadcast: bool = False) -> list[M]:
        """Messages to send this round: ``make(receiver)`` per neighbour, or one ``make(BROADCAST)``."""
        if broadcast:
            return [make(BROADCAST)]
        return [make(n) for n in self.neighbours]

    # ------------------------------------------------------------------ receive half
    def receive(self, items: Iterable[Message | Delivery]) -> int:
        """Route arrivals into the gather; return how many were taken (duplicates are taken once).

        Messages of other kinds, from non-neighbours, addressed to someone else, for rounds already
        already closed (those only refresh the stale value), or refused by ``accept`` are ignored.
        """
        taken = 0
        for item in items:
            msg = item.message if isinstance(item, Delivery) else item
            if not isinstance(msg, self.kind) or msg.sender not in self.neighbours:
                continue
            if msg.receiver not in (self.owner, BROADCAST):
                continue
            if self.accept is not None and not self.accept(msg):
                continue
            if msg.round <= self._closed:
                # late for its round: still the newest thing we know, a stale value for later rounds
                past = self._past.get(msg.sender)
                if past is None or msg.round > past.round:
                    self._past[msg.sender] = msg
                continue
            slot = self._by_round.setdefault(msg.round, {})
            if msg.sender not in slot:
                slot[msg.sender] = msg
                taken += 1
        return taken

    def close(self, round: int) -> GatherResult[M]:
        """Finish round ``round`` at its deadline and report fresh, stale and missing neighbours.

        Rounds must be closed in increasing order; a message for a round already closed still
        updates the neighbour's newest value (it may serve as a stale value later).
        """
        if round <= self._closed:
            raise ProtocolError(f"{self.owner}: round {round} closed after round {self._closed}")
        self._closed = round
        got = self._by_round.get(round, {})
        for k in sorted(k for k in self._by_round if k <= round):
            for n, msg in self._by_round.pop(k).items():
                past = self._past.get(n)
                if past is None or msg.round > past.round:
                    self._past[n] = msg
        fresh, stale, ages, missing, late = {}, {}, {}, [], []
        for n in self.neighbours:
            if n in got:
                fresh[n] = got[n]
                ages[n] = 0
                continue
            late.append(n)
            best = self._past.get(n)
            if best is None:
                missing.append(n)
            else:
                stale[n] = best
                ages[n] = round - best.round
        return GatherResult(
            round=round,
            fresh=MappingProxyType(fresh),
            stale=MappingProxyType(stale),
            ages=MappingProxyType(ages),
            missing=tuple(missing),
            late=tuple(late),
        )


def exchange_round(
    transport: Transport,
    gathers: Mapping[str, RoundGather[M]],
    make: Mapping[str, Callable[[str], M]],
    round: int,
    *,
    period: float,
    deadline: float,
    broadcast: bool = True,
) -> dict[str, GatherResult[M]]:
    """Run one synchronous round: every agent sends, then every agent gathers at its deadline.

    Parameters
    ----------
    transport : Transport
    gathers : Mapping[str, RoundGather]
        Agent -> its gather (agents without one only receive nothing).
    make : Mapping[str, callable]
        Agent -> ``make(receiver) -> Message`` for this round (agents absent here send nothing).
    round : int
    period, deadline : float
        Round ``k`` starts at ``k * period``; inboxes are read at ``k * period + deadline`` (s).
    broadcast : bool
        Send one broadcast per agent instead of one message per neighbour.

    Returns
    -------
    dict
        Agent -> :class:`GatherResult` of this round. Deliveries of other kinds are lost to the
        caller: run one transport per protocol, or route inboxes yourself.
    """
    if not 0 <= deadline:
        raise ProtocolError("deadline must be non-negative")
    t0 = round * period
    for agent, mk in make.items():
        gather = gathers.get(agent)
        msgs = gather.outgoing(mk, broadcast=broadcast) if gather is not None else [mk(BROADCAST)]
        for msg in msgs:
            transport.send(msg, t0)
    t1 = t0 + deadline
    out = {}
    for agent, gather in gathers.items():
        gather.receive(transport.poll(agent, t1))
        out[agent] = gather.close(round)
    return out
