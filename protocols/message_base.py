"""The base of every message kind (:class:`Message`: sender, receiver, round) and the registry of kinds (:func:`register`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from decentral.errors import ProtocolError
from protocols.fields import freeze, set_field
from protocols.wire import REGISTRY, WIRE_VERSION, decode, encode_frame, kind_id, payload_names

__all__ = ["BROADCAST", "MAX_NAME", "Message", "register", "registered_kinds"]

#: receiver marker of a message addressed to every other agent on the transport
BROADCAST = "*"
#: longest agent name (UTF-8 bytes)
MAX_NAME = 255


@dataclass(frozen=True, slots=True, eq=False, kw_only=True)
class Message:
    """Base of every message: who sent it, to whom, in which protocol round.

    Attributes
    ----------
    sender : str
        Name of the sending agent (1 to 255 UTF-8 bytes).
    receiver : str
        Name of the receiving agent, or :data:`BROADCAST` for every other agent.
    round : int
        Protocol round (iteration) the message belongs to; signed 64-bit.
    KIND : ClassVar[str]
        Kind name, unique in the registry (e.g. ``"admm.primal"``).
    """

    KIND: ClassVar[str] = ""

    sender: str
    receiver: str
    round: int

    def __post_init__(self) -> None:
        for name in ("sender", "receiver"):
            value = getattr(self, name)
            if not isinstance(value, str) or not value or len(value.encode("utf-8")) > MAX_NAME:
                raise ProtocolError(f"field {name!r}: must be a non-empty name of at most 255 bytes")
        if type(self.round) is not int:
            if isinstance(self.round, bool) or not isinstance(self.round, (int, np.integer)):
                raise ProtocolError(f"field 'round': must be an int, got {type(self.round).__name__}")
            set_field(self, "round", int(self.round))
        if not -(2**63) <= self.round < 2**63:
            raise ProtocolError("field 'round': out of the signed 64-bit range")
        for name in payload_names(type(self)):
            set_field(self, name, freeze(getattr(self, name), name))

    def __copy__(self) -> "Message":
        return self  # a value: frozen, its payload frozen (read-only arrays, mapping proxies)

    def __deepcopy__(self, memo) -> "Message":
        return self

    # ------------------------------------------------------------------ encoding
    @property
    def is_broadcast(self) -> bool:
        """Whether the message is addressed to every other agent."""
        return self.receiver == BROADCAST

    def payload_fields(self) -> tuple[str, ...]:
        """Names of the kind-specific fields, in wire order."""
        return payload_names(type(self))

    def to_bytes(self) -> bytes:
        """Encode the message as one wire frame (docs/wire_format.md gives the layout)."""
        return self._encode(WIRE_VERSION)

    def _encode(self, version: int) -> bytes:
        """Encode as a frame of wire ``version`` (1 only for compatibility tests)."""
        return encode_frame(self, version)

    @property
    def size_bytes(self) -> int:
        """Exact size of the wire frame in bytes."""
        return len(self.to_bytes())

    @classmethod
    def from_bytes(cls, data: bytes) -> "Message":
        """Decode one frame; on :class:`Message` itself any registered kind, on a subclass only that kind."""
        msg = decode(data)
        if cls is not Message and type(msg) is not cls:
            raise ProtocolError(f"expected a {cls.KIND!r} message, got {type(msg).KIND!r}")
        return msg

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Message):
            return NotImplemented
        return type(self) is type(other) and self.to_bytes() == other.to_bytes()

    def __hash__(self) -> int:
        return hash(self.to_bytes())


def register(cls: type[Message]) -> type[Message]:
    """Class decorator adding a message kind to the registry used by :func:`decode`.

    Raises
    ------
    ProtocolError
        If the class is not a frozen, slotted dataclass deriving from :class:`Message`, has no
        ``KIND``, or its kind id collides with another registered kind.
    """
    if not (isinstance(cls, type) and issubclass(cls, Message)) or cls is Message:
        raise ProtocolError("only subclasses of Message can be registered")
    if not isinstance(cls.KIND, str) or not cls.KIND:
        raise ProtocolError(f"{cls.__name__} has no KIND")
    params = getattr(cls, "__dataclass_params__", None)
    if params is None or not params.frozen or "__slots__" not in cls.__dict__:
        raise ProtocolError(f"{cls.__name__} must be a frozen, slotted dataclass")
    if "__eq__" in cls.__dict__ and cls.__eq__ is not Message.__eq__:
        raise ProtocolError(f"{cls.__name__} must be declared with eq=False (equality is by wire bytes)")
    kid = kind_id(cls.KIND)
    other = REGISTRY.get(kid)
    if other is not None and (other.KIND != cls.KIND or other.__qualname__ != cls.__qualname__):
        raise ProtocolError(f"kind {cls.KIND!r} collides with registered kind {other.KIND!r} (id {kid})")
    REGISTRY[kid] = cls
    return cls


def registered_kinds() -> dict[str, type[Message]]:
    """Return kind name -> class for every registered kind."""
    return {c.KIND: c for c in REGISTRY.values()}
