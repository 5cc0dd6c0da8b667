"""Typed, immutable messages and their versioned binary wire encoding: one import for every shipped kind.

Every message is a frozen, slotted, keyword-only dataclass deriving from :class:`Message`
(:mod:`protocols.message_base`), encoded without pickle by the codec of :mod:`protocols.wire`
(docs/wire_format.md: the frame layout, the supported values, how to add a kind); its fields are
checked by the validators of :mod:`protocols.fields`. Each kind lives beside the protocol that sends
it (:mod:`protocols.swarm_messages`, :mod:`protocols.admm_values`, :mod:`protocols.heartbeat`,
:mod:`protocols.admm_messages`, ...); this module re-exports the base, the codec's public names and
the kinds above.
"""

from protocols.admm_values import AdmmDual, AdmmPrimal
from protocols.fields import as_array, finite_array, finite_float, set_field
from protocols.heartbeat import Heartbeat
from protocols.message_base import BROADCAST, Message, register, registered_kinds
from protocols.swarm_messages import OdometryReport, PoseEstimates, Tracks
from protocols.wire import HEADER_SIZE, MAGIC, WIRE_VERSION, CorruptFrame, checked_shape, decode, kind_id

__all__ = [
    "BROADCAST",
    "MAGIC",
    "WIRE_VERSION",
    "HEADER_SIZE",
    "Message",
    "register",
    "registered_kinds",
    "kind_id",
    "decode",
    "as_array",
    "checked_shape",
    "CorruptFrame",
    "Tracks",
    "PoseEstimates",
    "AdmmPrimal",
    "AdmmDual",
    "Heartbeat",
    "OdometryReport",
]

# the names these helpers had when they were private to this module, for code written against them
_set = set_field
_finite_array = finite_array
_finite_float = finite_float
