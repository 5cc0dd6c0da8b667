"""Every registered message kind passes message_kind_test."""

from dataclasses import dataclass
from typing import ClassVar

import pytest

from protocols.conformance import message_kind_test
from protocols.message_base import REGISTRY, kind_id
from protocols.messages import Message, register, registered_kinds
from tests.protocols.frame_fuzz import sample_messages  # also imports every package that registers kinds

SAMPLES: dict = {}
for _msg in sample_messages():
    SAMPLES.setdefault(type(_msg), []).append(_msg)

SHIPPED = sorted(kind for kind, cls in registered_kinds().items() if cls.__module__.startswith("protocols."))


@pytest.mark.parametrize("kind", SHIPPED)
def test_message_kind_conforms(kind):
    """The kind round-trips, reports its size, is frozen, and only raises ProtocolError on damaged frames."""
    cls = registered_kinds()[kind]
    assert cls in SAMPLES, f"add an example of {kind!r} to tests/protocols/frame_fuzz.py::sample_messages"
    message_kind_test(cls, SAMPLES[cls])


@dataclass(frozen=True, slots=True, eq=False, kw_only=True)
class _Drifting(Message):
    """A kind whose normalization is not idempotent: decoding its frame gives another message."""

    KIND: ClassVar[str] = "test.drifting"
    count: int

    def __post_init__(self) -> None:
        Message.__post_init__(self)
        object.__setattr__(self, "count", int(self.count) + 1)


@dataclass(frozen=True, slots=True, eq=False, kw_only=True)
class _Unregistered(Message):
    """A kind nobody registered."""

    KIND: ClassVar[str] = "test.unregistered"
    count: int


def test_message_kind_test_catches_a_round_trip_that_drifts():
    """A kind whose decoded frame differs from the message fails message_kind_test, pointing at __post_init__."""
    register(_Drifting)
    try:
        with pytest.raises(AssertionError, match="__post_init__"):
            message_kind_test(_Drifting, [_Drifting(sender="A0", receiver="A1", round=1, count=2)])
    finally:  # registered for this test only: the registry is global, and the decoder fuzz draws from it
        REGISTRY.pop(kind_id(_Drifting.KIND))


def test_message_kind_test_asks_for_registration():
    """An unregistered kind fails message_kind_test with a message naming @register."""
    with pytest.raises(AssertionError, match="register"):
        message_kind_test(_Unregistered, [])
