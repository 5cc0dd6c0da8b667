"""The sending half of a module agent: its outbox, per-phase counts, and acknowledgement with retransmission."""

from __future__ import annotations

from collections import Counter

from protocols.ensemble.messages import SUBPHASE_OF, Ack, ClusterClaim, Hello, Join, TreeFlood
from protocols.messages import Message

__all__ = ["Link", "step_of"]


def step_of(msg: Message) -> str:
    """The step (phase name) a message belongs to, as its acknowledgement and the counts name it."""
    if isinstance(msg, Hello):
        return "neighbor_detection"
    if isinstance(msg, (TreeFlood, Join)):
        return "leader_election"
    if isinstance(msg, ClusterClaim):
        return "graph_abstraction"
    return msg.phase


class Link:
    """One module's messages out: what it sends, counted per phase, and (when ``reliable``) acknowledged.

    With ``reliable`` every message but an acknowledgement carries a sequence number and is sent again
    every ``retry_rounds`` rounds until its receiver acknowledges it; the receiver acknowledges every
    copy and drops the duplicates (:meth:`accept`).
    """

    def __init__(self, name: str, reliable: bool, retry_rounds: int):
        self.name = name
        self.reliable = reliable
        self.retry_rounds = retry_rounds
        self.round = 0
        self.outbox: list[Message] = []
        self.sent = Counter()  # messages sent per phase
        self.seq = 0
        self.pending: dict[tuple[int, int], list] = {}
        self.seen: set[tuple[int, int]] = set()

    def send(self, msg_type, receiver: int, step: str, reliable: bool = True, **fields) -> None:
        """Queue a ``msg_type`` message for ``receiver`` in ``step`` (counted under the step's phase)."""
        seq = -1
        if reliable and self.reliable:
            seq = self.seq
            self.seq += 1
        msg = msg_type(sender=self.name, receiver=str(receiver), round=self.round, seq=seq, **fields) \
            if msg_type is not Ack else msg_type(sender=self.name, receiver=str(receiver), round=self.round, **fields)
        self.outbox.append(msg)
        self.sent[SUBPHASE_OF.get(step, step)] += 1
        if seq >= 0:
            self.pending[(receiver, seq)] = [msg, step, None]  # None: not yet handed to the network

    def accept(self, sender: int, msg: Message) -> bool:
        """Acknowledge ``msg`` if it asks for it; whether it is new (not an ack, not a duplicate)."""
        if isinstance(msg, Ack):
            self.pending.pop((sender, msg.seq), None)
            return False
        seq = getattr(msg, "seq", -1)
        if seq >= 0:
            self.send(Ack, sender, step_of(msg), reliable=False, seq=seq, phase=step_of(msg))
            if (sender, seq) in self.seen:
                return False
            self.seen.add((sender, seq))
        return True

    def take(self, round_: int) -> list[Message]:
        """Retransmit what is overdue at ``round_`` and hand over the outbox."""
        if self.pending:
            for item in self.pending.values():
                msg, step, sent_at = item
                if sent_at is None:  # its first copy leaves in this outbox: the retry clock starts now
                    item[2] = round_
                elif round_ - sent_at >= self.retry_rounds:
                    self.outbox.append(msg)
                    self.sent[SUBPHASE_OF.get(step, step)] += 1
                    item[2] = round_
        out, self.outbox = self.outbox, []
        return out

    @property
    def busy(self) -> bool:
        """Whether something waits to be sent or to be acknowledged."""
        return bool(self.outbox or self.pending)
