"""Conformance check of a message kind: :func:`message_kind_test` drives a :class:`~protocols.messages.Message` subclass through its contract.

A kind must be registered, frozen and slotted, encode to one wire frame whose size it reports exactly,
decode back to an equal message, refuse other kinds' frames on ``from_bytes``, and turn any damaged
or hostile buffer into :class:`decentral.errors.ProtocolError` and nothing else. The check raises
:class:`AssertionError` with a message saying what to fix, in the manner of PettingZoo's
``parallel_api_test``; docs/conformance.md shows how to check your own kind.
"""

from __future__ import annotations

import dataclasses
import struct
import zlib
from typing import Sequence

import numpy as np

from decentral.errors import ProtocolError
from protocols.messages import HEADER_SIZE, Heartbeat, Message, Tracks, decode, kind_id, registered_kinds

__all__ = ["message_kind_test", "reseal"]


def _require(ok: bool, who: str, message: str) -> None:
    if not ok:
        raise AssertionError(f"{who}: {message}")


def reseal(frame: bytes, body: bytes | None = None) -> bytes:
    """``frame`` with ``body`` (default: its own) behind a header whose length and checksum fit it.

    A mutated body resealed this way passes the framing checks, so the mutation reaches the kind's
    field parser and validators.
    """
    body = frame[HEADER_SIZE:] if body is None else body
    head = frame[:8] + struct.pack("<I", len(body))
    return head + struct.pack("<I", zlib.crc32(body, zlib.crc32(head))) + body


def _mutations(frame: bytes, rng: np.random.Generator, count: int) -> list[bytes]:
    """Truncations at every length, then ``count`` resealed random byte edits of the body."""
    out = [frame[:n] for n in range(len(frame))]
    body = frame[HEADER_SIZE:]
    for _ in range(count):
        b = bytearray(body)
        op = rng.integers(0, 4)
        if not b:
            op = 3
        if op == 0:  # flip bits
            for _ in range(int(rng.integers(1, 4))):
                b[int(rng.integers(0, len(b)))] ^= 1 << int(rng.integers(0, 8))
        elif op == 1:  # extreme bytes (lengths, counts, dtype codes)
            at = int(rng.integers(0, len(b)))
            b[at:at + 4] = bytes([0xFF, 0xFF, 0xFF, 0x7F][: len(b[at:at + 4])])
        elif op == 2:  # delete a range
            at = int(rng.integers(0, len(b)))
            del b[at:at + int(rng.integers(1, 9))]
        else:  # insert random bytes
            at = int(rng.integers(0, len(b) + 1))
            b[at:at] = rng.integers(0, 256, int(rng.integers(1, 9)), dtype=np.uint8).tobytes()
        out.append(reseal(frame, bytes(b)))
    return out


def message_kind_test(cls: type, examples: Sequence[Message], *, seed: int = 0, fuzz: int = 300) -> None:
    """Check that the message kind ``cls`` keeps the wire contract; raise ``AssertionError`` if not.

    The rules: ``cls`` derives from :class:`~protocols.messages.Message`, has a ``KIND`` and is the
    registered class of that kind (:func:`~protocols.messages.register`); every example is an instance
    of it, immutable (setting a field raises), and equal to itself decoded from its own frame by both
    :func:`~protocols.messages.decode` and ``cls.from_bytes``, with ``size_bytes == len(to_bytes())``;
    equal messages hash alike; ``cls.from_bytes`` refuses another kind's frame with
    :class:`~decentral.errors.ProtocolError`; and every truncation of a frame and ``fuzz`` resealed
    random edits of its body (seeded by ``seed``) either decode to a message of this kind or raise
    :class:`~decentral.errors.ProtocolError`, never another exception.

    Parameters
    ----------
    cls : type
        The message class.
    examples : sequence of Message
        One or more valid messages of the kind (vary the fields: empty and full arrays, None, ...).
    seed, fuzz : int
        Seed and count of the random body edits per example.

    Examples
    --------
    >>> from protocols.messages import Heartbeat
    >>> message_kind_test(Heartbeat, [Heartbeat(sender="A0", receiver="A1", round=3, t=4.0)])
    """
    who = f"message_kind_test({getattr(cls, '__name__', cls)!r})"
    _require(isinstance(cls, type) and issubclass(cls, Message) and cls is not Message, who,
             "must be a subclass of protocols.messages.Message")
    _require(isinstance(cls.KIND, str) and bool(cls.KIND), who, "needs a KIND class variable (e.g. 'mine.gossip')")
    _require(registered_kinds().get(cls.KIND) is cls, who,
             f"kind {cls.KIND!r} is not registered to this class: decorate it with @protocols.messages.register")
    params = getattr(cls, "__dataclass_params__", None)
    _require(params is not None and params.frozen and "__slots__" in cls.__dict__, who,
             "must be declared @dataclass(frozen=True, slots=True, eq=False, kw_only=True)")
    _require(len(examples) > 0, who, "give at least one example message")
    other: Message = Heartbeat(sender="conformance", receiver="other", round=0, t=0.0)
    if cls is Heartbeat:  # any other kind will do
        other = Tracks(sender="conformance", receiver="other", round=0, t=0.0, camera="A/c", ids=[1],
                       uvr=[[1.0, 2.0, 3.0]])
    foreign = other.to_bytes()
    rng = np.random.default_rng(seed)
    for n, msg in enumerate(examples):
        tag = f"example {n}"
        _require(type(msg) is cls, who, f"{tag} is a {type(msg).__name__}, not a {cls.__name__}")
        frame = msg.to_bytes()
        _require(isinstance(frame, bytes) and msg.size_bytes == len(frame), who,
                 f"{tag}: size_bytes {msg.size_bytes} != len(to_bytes()) {len(frame)}")
        _require(int.from_bytes(frame[6:8], "little") == kind_id(cls.KIND), who, f"{tag}: the frame names another kind")
        back = decode(frame)
        _require(type(back) is cls and back == msg and back.to_bytes() == frame, who,
                 f"{tag}: decode(to_bytes()) does not give the message back; check that __post_init__ normalizes "
                 f"every field the same way on both sides (arrays with as_array, tuples as tuples)")
        _require(cls.from_bytes(frame) == msg and hash(back) == hash(msg), who,
                 f"{tag}: from_bytes or hash disagree with the decoded message")
        for f in dataclasses.fields(msg):
            try:
                setattr(msg, f.name, getattr(msg, f.name))
            except (dataclasses.FrozenInstanceError, AttributeError, TypeError):
                continue
            raise AssertionError(f"{who}: {tag}: field {f.name!r} can be reassigned; messages must be frozen")
        try:
            cls.from_bytes(foreign)
        except ProtocolError:
            pass
        except Exception as exc:  # noqa: BLE001 - reporting which exception escaped is the point
            raise AssertionError(f"{who}: from_bytes of another kind's frame raised {type(exc).__name__}, "
                                 f"not ProtocolError") from exc
        else:
            raise AssertionError(f"{who}: from_bytes accepted a frame of another kind")
        for k, bad in enumerate(_mutations(frame, rng, fuzz)):
            try:
                got = decode(bad)
            except ProtocolError:
                continue
            except Exception as exc:  # noqa: BLE001
                raise AssertionError(
                    f"{who}: {tag}: a damaged frame ({'truncated to %d bytes' % len(bad) if k < len(frame) else 'edited body'}"
                    f", {bad.hex()[:80]}...) raised {type(exc).__name__}: {exc}; validate fields in __post_init__ and "
                    f"raise decentral.errors.ProtocolError") from exc
            _require(isinstance(got, Message), who, f"{tag}: decode returned {type(got).__name__} for a damaged frame")

