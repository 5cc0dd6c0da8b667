"""Wire encoding of protocol messages: round trips, exact sizes, and rejection of bad frames."""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from decentral.errors import ProtocolError
from protocols.messages import (
    BROADCAST,
    HEADER_SIZE,
    AdmmDual,
    AdmmPrimal,
    Heartbeat,
    Message,
    OdometryReport,
    PoseEstimates,
    Tracks,
    decode,
    register,
    registered_kinds,
)

names = st.text(alphabet=st.characters(codec="utf-8", exclude_categories=("Cs",)), min_size=1, max_size=20)
finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
rounds = st.integers(-(2**63), 2**63 - 1)


@st.composite
def tracks(draw):
    n = draw(st.integers(0, 6))
    ids = draw(st.lists(st.integers(-(2**40), 2**40), min_size=n, max_size=n, unique=True))
    uvr = draw(hnp.arrays(np.float64, (n, 3), elements=finite))
    return Tracks(
        sender=draw(names), receiver=draw(st.one_of(names, st.just(BROADCAST))), round=draw(rounds),
        t=draw(finite), camera=draw(names) + "/" + draw(names), ids=ids, uvr=uvr,
    )


@st.composite
def admm(draw):
    keys = draw(st.lists(names, max_size=4, unique=True))
    blocks = {
        k: draw(hnp.arrays(np.float64, hnp.array_shapes(min_dims=0, max_dims=3, max_side=4), elements=finite))
        for k in keys
    }
    common = dict(sender=draw(names), receiver=draw(names), round=draw(rounds), window=draw(rounds), blocks=blocks)
    if draw(st.booleans()):
        return AdmmPrimal(**common)
    return AdmmDual(**common, rho=draw(st.floats(1e-9, 1e9)))


@st.composite
def poses(draw):
    subjects = tuple(draw(st.lists(names, max_size=5, unique=True)))
    n = len(subjects)
    return PoseEstimates(
        sender=draw(names), receiver=BROADCAST, round=draw(rounds), t=draw(finite), subjects=subjects,
        poses=draw(hnp.arrays(np.float64, (n, 3), elements=finite)),
        covariances=draw(hnp.arrays(np.float64, (n, 3, 3), elements=finite)),
    )


any_message = st.one_of(
    tracks(), admm(), poses(),
    st.integers(1, 4).flatmap(lambda L: st.builds(
        lambda s, t, m, c: OdometryReport(sender=s, receiver=BROADCAST, round=7, t=t, motions=m, covariances=c),
        names, finite, hnp.arrays(np.float64, (L, 3), elements=finite), hnp.arrays(np.float64, (L, 3, 3), elements=finite))),
    st.builds(lambda s, r, k, t: Heartbeat(sender=s, receiver=r, round=k, t=t), names, names, rounds, finite),
)


@settings(max_examples=150, deadline=None)
@given(any_message)
def test_round_trip_is_identity(msg):
    """decode(to_bytes(m)) equals m field by field, for every kind."""
    back = decode(msg.to_bytes())
    assert type(back) is type(msg) and back == msg
    for name in ("sender", "receiver", "round", *msg.payload_fields()):
        a, b = getattr(msg, name), getattr(back, name)
        if isinstance(a, np.ndarray):
            assert a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b)
        elif hasattr(a, "keys"):
            assert list(a) == list(b) and all(np.array_equal(a[k], b[k]) for k in a)
        else:
            assert a == b


@settings(max_examples=60, deadline=None)
@given(any_message)
def test_size_bytes_is_exact(msg):
    """size_bytes equals the length of the encoded frame."""
    assert msg.size_bytes == len(msg.to_bytes())


@settings(max_examples=80, deadline=None)
@given(any_message, st.data())
def test_any_truncation_is_rejected(msg, data):
    """Every proper prefix of a frame raises ProtocolError and nothing else."""
    frame = msg.to_bytes()
    cut = data.draw(st.integers(0, len(frame) - 1))
    with pytest.raises(ProtocolError):
        decode(frame[:cut])


@settings(max_examples=80, deadline=None)
@given(any_message, st.data())
def test_any_byte_flip_is_rejected(msg, data):
    """Changing any one byte of a frame raises ProtocolError (magic, version, length or CRC)."""
    frame = bytearray(msg.to_bytes())
    pos = data.draw(st.integers(0, len(frame) - 1))
    frame[pos] ^= data.draw(st.integers(1, 255))
    with pytest.raises(ProtocolError):
        decode(bytes(frame))


@settings(max_examples=100, deadline=None)
@given(st.binary(max_size=300))
def test_random_bytes_never_crash(blob):
    """Arbitrary bytes either decode or raise ProtocolError, never another exception."""
    try:
        decode(blob)
    except ProtocolError:
        pass


def _reframe(frame: bytes, *, magic=None, version=None, kid=None, body=None) -> bytes:
    """Rebuild a frame with some header fields or the body replaced, with a valid CRC."""
    m, v, f, k, _, _ = struct.unpack_from("<4sBBHII", frame)
    body = frame[HEADER_SIZE:] if body is None else body
    head = struct.pack("<4sBBHI", magic or m, v if version is None else version, f, k if kid is None else kid, len(body))
    return head + struct.pack("<I", zlib.crc32(body, zlib.crc32(head))) + body


HB = Heartbeat(sender="A0", receiver="A1", round=4, t=1.5)


@pytest.mark.parametrize(
    "mutate, words",
    [
        (lambda f: _reframe(f, magic=b"XXXX"), "magic"),
        (lambda f: _reframe(f, version=9), "version"),
        (lambda f: _reframe(f, kid=(zlib.crc32(b"tracks") + 1) & 0xFFFF), "unknown message kind"),
        (lambda f: f + b"\x00", "length mismatch"),
        (lambda f: f[:-1] + bytes([f[-1] ^ 1]), "checksum"),
        (lambda f: _reframe(f, body=f[HEADER_SIZE:] + b"\x00"), "trailing"),
        (lambda f: _reframe(f, body=f[HEADER_SIZE:-9]), "truncated"),
    ],
)
def test_corruption_messages_are_clear(mutate, words):
    """Each defect is reported by a ProtocolError whose text names it."""
    with pytest.raises(ProtocolError, match=words):
        decode(mutate(HB.to_bytes()))


def test_bad_array_payload_is_rejected():
    """A version-1 frame whose .npy payload is malformed (with a valid CRC) raises ProtocolError."""
    msg = AdmmPrimal(sender="a", receiver="b", round=1, window=0, blocks={"x": np.arange(3.0)})
    frame = msg._encode(1)
    body = bytearray(frame[HEADER_SIZE:])
    at = bytes(body).index(b"\x93NUMPY")
    body[at + 1 : at + 6] = b"NOPE!"
    with pytest.raises(ProtocolError, match="bad array"):
        decode(_reframe(frame, body=bytes(body)))


def test_object_arrays_cannot_be_sent():
    """Object-dtype arrays are refused at construction, so pickle is never needed."""
    with pytest.raises(ProtocolError):
        AdmmPrimal(sender="a", receiver="b", round=1, window=0, blocks={"x": np.array([{}], dtype=object)})


def test_kind_validation_runs_on_decode():
    """A frame carrying values its kind rejects (non-finite pose) raises ProtocolError on decode."""
    ok = PoseEstimates(sender="a", receiver="*", round=0, t=0.0, subjects=("b",), poses=[[1.25, 0.0, 0.0]],
                       covariances=np.zeros((1, 3, 3)))
    frame = ok.to_bytes()
    body = frame[HEADER_SIZE:]
    raw = np.array([[1.25, 0.0, 0.0]]).tobytes()
    bad = body.replace(raw, np.array([[np.nan, 0, 0]]).tobytes(), 1)
    assert bad != body
    with pytest.raises(ProtocolError, match="finite"):
        decode(_reframe(frame, body=bad))


def test_messages_are_immutable():
    """Fields cannot be reassigned and arrays inside messages are read-only."""
    msg = Tracks(sender="a", receiver="b", round=0, t=0.0, camera="a/c", ids=[1], uvr=[[1.0, 2.0, 3.0]])
    with pytest.raises(AttributeError):
        msg.round = 2
    with pytest.raises(ValueError):
        msg.uvr[0, 0] = 5.0


def test_input_arrays_are_copied():
    """Mutating the caller's array after construction does not change the message."""
    uvr = np.array([[1.0, 2.0, 3.0]])
    msg = Tracks(sender="a", receiver="b", round=0, t=0.0, camera="a/c", ids=[1], uvr=uvr)
    uvr[0, 0] = 99.0
    assert msg.uvr[0, 0] == 1.0


def test_from_bytes_on_a_kind_checks_the_kind():
    """Tracks.from_bytes refuses a Heartbeat frame; Message.from_bytes accepts any kind."""
    frame = HB.to_bytes()
    assert Message.from_bytes(frame) == HB
    with pytest.raises(ProtocolError, match="expected"):
        Tracks.from_bytes(frame)


def test_new_kinds_register_and_round_trip():
    """A subclass declared as documented registers, dispatches through decode, and round-trips."""

    @register
    @dataclass(frozen=True, slots=True, eq=False, kw_only=True)
    class Probe(Message):
        KIND: ClassVar[str] = "test.probe"
        label: str
        values: tuple = ()
        meta: dict | None = None

    msg = Probe(sender="x", receiver="y", round=2, label="hi", values=(1, 2.5, "s", None, True),
                meta={"a": np.eye(2), "b": (1, 2)})
    back = decode(msg.to_bytes())
    assert isinstance(back, Probe) and back == msg and back.values == (1, 2.5, "s", None, True)
    assert "test.probe" in registered_kinds()


def test_kind_id_collisions_are_refused():
    """Registering a different class under an existing kind name raises ProtocolError."""

    @dataclass(frozen=True, slots=True, eq=False, kw_only=True)
    class Impostor(Message):
        KIND: ClassVar[str] = "heartbeat"

    with pytest.raises(ProtocolError, match="collides"):
        register(Impostor)


def test_unregistered_classes_cannot_encode():
    """A Message subclass that was never registered refuses to_bytes."""

    @dataclass(frozen=True, slots=True, eq=False, kw_only=True)
    class Loose(Message):
        KIND: ClassVar[str] = "test.loose"

    with pytest.raises(ProtocolError, match="not registered"):
        Loose(sender="a", receiver="b", round=0).to_bytes()


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(sender="", receiver="b", round=0, t=0.0),
        dict(sender="a", receiver="b", round=1.5, t=0.0),
        dict(sender="a", receiver="b", round=0, t=float("inf")),
        dict(sender="a" * 300, receiver="b", round=0, t=0.0),
    ],
)
def test_bad_fields_raise_protocol_error(kwargs):
    """Constructing a message with invalid envelope or field values raises ProtocolError."""
    with pytest.raises(ProtocolError):
        Heartbeat(**kwargs)


def test_tracks_shapes_are_checked():
    """Tracks with mismatched ids and uvr rows, or duplicate ids, are refused."""
    with pytest.raises(ProtocolError):
        Tracks(sender="a", receiver="b", round=0, t=0.0, camera="a/c", ids=[1, 2], uvr=[[1.0, 2.0, 3.0]])
    with pytest.raises(ProtocolError, match="duplicate"):
        Tracks(sender="a", receiver="b", round=0, t=0.0, camera="a/c", ids=[1, 1], uvr=np.ones((2, 3)))


@settings(max_examples=60, deadline=None)
@given(st.one_of(st.lists(finite, min_size=1, max_size=12), st.lists(st.integers(-(2**63), 2**63 - 1), min_size=1,
                                                                      max_size=12)))
def test_homogeneous_tuples_round_trip_compactly(values):
    """Tuples of only floats or only ints round-trip exactly in 8 bytes per element (+5 bytes)."""
    from dataclasses import dataclass as dc

    @register
    @dc(frozen=True, slots=True, eq=False, kw_only=True)
    class Packed(Message):
        KIND: ClassVar[str] = "test.packed"
        values: tuple

    msg = Packed(sender="a", receiver="b", round=0, values=tuple(values))
    back = decode(msg.to_bytes())
    assert back.values == tuple(values) and [type(v) for v in back.values] == [type(v) for v in values]
    empty = Packed(sender="a", receiver="b", round=0, values=())
    assert msg.size_bytes - empty.size_bytes == 8 * len(values)


def test_version_one_frames_still_decode():
    """A frame in wire version 1 (arrays as .npy) decodes to the same message as version 2."""
    msg = AdmmDual(sender="a", receiver="b", round=3, window=2, rho=0.5,
                   blocks={"x": np.arange(16.0).reshape(2, 8), "meta": np.ones(4)})
    old = msg._encode(1)
    assert old[4] == 1 and msg.to_bytes()[4] == 2
    assert decode(old) == msg


def test_version_two_arrays_carry_no_npy_header():
    """A version-2 array costs its dtype code, ndim, shape and raw data: 2 + 4 ndim + itemsize * size bytes."""
    small = AdmmPrimal(sender="a", receiver="b", round=1, window=0, blocks={"x": np.zeros((0,))})
    big = AdmmPrimal(sender="a", receiver="b", round=1, window=0, blocks={"x": np.zeros((5, 8))})
    assert big.size_bytes - small.size_bytes == 4 + 8 * 40


@pytest.mark.parametrize("patch, words", [
    (lambda raw: bytes([99]) + raw[1:], "dtype code"),
    (lambda raw: raw[:1] + bytes([200]) + raw[2:], "ndim"),
    (lambda raw: raw[:2] + struct.pack("<I", 1000) + raw[6:], "truncated"),
])
def test_malformed_raw_arrays_are_rejected(patch, words):
    """A version-2 array with an unknown dtype code, absurd ndim or a shape larger than its data is rejected."""
    msg = AdmmPrimal(sender="a", receiver="b", round=1, window=0, blocks={"x": np.arange(3.0)})
    frame = msg.to_bytes()
    body = frame[HEADER_SIZE:]
    at = body.index(b"A" + bytes([12, 1]))
    raw = body[at + 1:]
    with pytest.raises(ProtocolError, match=words):
        decode(_reframe(frame, body=body[:at + 1] + patch(raw)))


def test_raw_bool_arrays_reject_bytes_other_than_zero_and_one():
    """A version-2 bool array whose bytes are not 0/1 is rejected (never reinterpreted)."""
    from protocols.wire import Reader
    with pytest.raises(ProtocolError, match="bool"):
        Reader(b"A" + bytes([1, 1]) + struct.pack("<I", 2) + b"\x01\x07").value("x")
