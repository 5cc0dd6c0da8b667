"""The liveness beacon every transport and agent may send (:class:`Heartbeat`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from protocols.fields import finite_float, set_field
from protocols.message_base import Message, register

__all__ = ["Heartbeat"]


@register
@dataclass(frozen=True, slots=True, eq=False, kw_only=True)
class Heartbeat(Message):
    """A liveness beacon: the sender is up at time ``t`` and has reached ``round``."""

    KIND: ClassVar[str] = "heartbeat"

    t: float

    def __post_init__(self) -> None:
        Message.__post_init__(self)
        set_field(self, "t", finite_float(self.t, "t"))
