"""A seeded generator of hostile wire frames for the decoder fuzz tests.

Three families, drawn in turn: (1) valid frames of every registered kind with their bytes mutated
(flips, extreme integers, inserted, deleted, repeated or spliced ranges), resealed with a correct
length and CRC most of the time so that the mutation reaches the body parser rather than the
checksum; (2) frames of a registered kind whose fields are random wire values of any type (NaN ids,
float arrays where ints are due, zero-element arrays with huge dimensions, nested tuples and maps);
(3) raw random bytes, sometimes behind a valid header.
"""

from __future__ import annotations

import struct
import zlib
from typing import Iterator

import numpy as np

import protocols.admm_messages  # noqa: F401  (registers its kinds)
import protocols.ensemble.messages  # noqa: F401
from protocols.admm_messages import ConfigAnnounce, ConfigRequest, FactorShare, FormAck, FormBundle
from protocols.delta_messages import DeltaBundle, FactorDelta, JointPoses
from protocols.baselines.flood import RawStep
from protocols.ensemble.messages import Ack, ClusterClaim, Command, Hello, Join, PoseShare, Report, TreeFlood
from protocols.messages import (
    HEADER_SIZE,
    MAGIC,
    AdmmDual,
    AdmmPrimal,
    Heartbeat,
    OdometryReport,
    PoseEstimates,
    Tracks,
    kind_id,
    registered_kinds,
)
from protocols.wire import encode_str, encode_value

__all__ = ["ISSUE_FRAME", "sample_messages", "reseal", "hostile_frames"]

#: the 76-byte frame with a valid CRC whose zero-element array of overflowing dimensions escaped as ValueError
ISSUE_FRAME = bytes.fromhex(
    "44434e54020047e43c00000091f2bc2b020000004131020000004130010000000000000002006900000000000000006d"
    "010000000100000078410c0400000000ffffffffffffffffffffffff"
)


def sample_messages() -> list:
    """One or two valid messages of every kind registered by the protocol packages."""
    common = dict(sender="A0", receiver="A1", round=3)
    forms = np.arange(1 + 1 + 45 + 3, dtype=float)[: 3 * 3 * 10 // 2 + 3 + 2]
    return [
        Tracks(**common, t=0.5, camera="A0/cam0", ids=[5, 7], uvr=[[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]),
        PoseEstimates(**common, t=1.0, subjects=("A1",), poses=[[0.1, 0.2, 0.3]], covariances=[np.eye(3)]),
        AdmmPrimal(**common, window=2, blocks={"A1": np.ones((2, 3))}),
        AdmmDual(**common, window=2, blocks={"A1": np.ones(3)}, rho=2.0),
        Heartbeat(**common, t=4.0),
        OdometryReport(**common, t=2.0, motions=[[0.1, 0.0, 0.01]], covariances=[np.eye(3)]),
        ConfigAnnounce(**common, step=1, ids=[0, 1], centres=[[0.0, 0, 0], [0.2, 0, 0]], owner="A0"),
        ConfigRequest(**common, ids=[4, 9]),
        FactorShare(**common, step=1, have=[0], keys=[[0, 0, 1], [0, 1, 1], [0, 2, 1]], forms=forms, pin=[]),
        FormBundle(**common, step=1, down=False, hop=1, parent=0, depth=1, start=0, members=[1], owners=[1],
                   keys=[[0, 0, 1], [0, 1, 1], [0, 2, 1]], forms=forms, pin=[1.0, 0, 0, 0, 0]),
        FormAck(**common, step=1, have=[0, 2]),
        Hello(**common, z=(0.05, 0.0)),
        TreeFlood(**common, level=0, group=1, hops=2, seq=4),
        Join(**common, level=0, group=1),
        ClusterClaim(**common, level=1, group=1, leader=1, hops=0),
        Report(**common, level=0, group=1, phase="count", payload={"n": np.array([3])}),
        Command(**common, level=0, group=1, phase="cut", payload={"side": np.array([0, 1], dtype=np.int8)}),
        PoseShare(**common, level=0, group=1, phase="refine", iteration=2, pose=np.arange(6.0).tobytes()),
        Ack(**common, seq=4, phase="refine"),
        DeltaBundle(**common, step=3, hop=2, parent=1, depth=4, members=np.array([0, 2]), pin=np.zeros(0),
                    digest=np.array([[4, 12345], [0, 0]]),
                    **DeltaBundle.pack(3, {0: [(((0, 3), (2, 3)), np.eye(6), np.array([1.0, 2.0]), 0.5, 6)]})),
        FactorDelta(**common, step=3, have=np.array([0, 2]), pin=np.zeros(0), digest=np.array([2, 4321]),
                    **FactorDelta.pack(3, [(((0, 3), (2, 3)), np.eye(6), np.array([1.0, 2.0]), 0.5, 6)])),
        JointPoses(**common, step=2, hop=0, parent=-1, depth=2, start=5, n=5, members=JointPoses.mask(range(5), 5),
                   index=JointPoses.mask([0, 1, 3], 5),
                   poses=np.array([[0, 0, 0, 0], [1.5, -0.25, 0.01, 0.3], [2.0, 1.0, 0.0, -3.1]]),
                   placeable=JointPoses.mask([1, 3], 5), edges=JointPoses.mask([1, 8], 25)),
        RawStep(**common, t=0.2, ids=[5, 7], uvr=[[611.2, 402.9, 23.1], [650.4, 398.2, 22.0]],
                odometry=[0.01, 0.0, 0.0, 0.002]),
    ]


def reseal(frame: bytes, *, kid: int | None = None, version: int | None = None) -> bytes:
    """``frame`` with its header's length and CRC made correct (and optionally another kind id / version)."""
    body = frame[HEADER_SIZE:]
    _, ver, flags, k = struct.unpack_from("<4sBBH", frame.ljust(8, b"\0"))
    head = struct.pack("<4sBBHI", MAGIC, ver if version is None else version, flags, k if kid is None else kid, len(body))
    return head + struct.pack("<I", zlib.crc32(body, zlib.crc32(head))) + body


_EXTREMES = (b"\x00", b"\xff", b"\x7f", b"\x80", b"\x00\x00\x00\x00", b"\xff\xff\xff\xff", b"\x00\x00\x00\x80",
             b"\xff\xff\xff\x7f", struct.pack("<d", float("nan")), struct.pack("<d", float("inf")),
             struct.pack("<d", 1e308), struct.pack("<q", -(2**63)), struct.pack("<Q", 2**64 - 1))


def _mutate(rng: np.random.Generator, frame: bytes, corpus: list[bytes]) -> bytes:
    data = bytearray(frame)
    for _ in range(int(rng.integers(1, 4))):
        op = int(rng.integers(7))
        at = int(rng.integers(HEADER_SIZE, max(len(data), HEADER_SIZE + 1)))
        if op == 0 and len(data) > HEADER_SIZE:  # flip bits of one byte
            data[min(at, len(data) - 1)] ^= int(rng.integers(1, 256))
        elif op == 1:  # overwrite with an extreme value
            v = _EXTREMES[int(rng.integers(len(_EXTREMES)))]
            data[at : at + len(v)] = v
        elif op == 2:  # insert random bytes
            data[at:at] = rng.bytes(int(rng.integers(1, 9)))
        elif op == 3:  # delete a range
            del data[at : at + int(rng.integers(1, 17))]
        elif op == 4:  # repeat a range
            data[at:at] = data[at : at + int(rng.integers(1, 33))]
        elif op == 5:  # splice the tail of another frame
            other = corpus[int(rng.integers(len(corpus)))]
            cut = int(rng.integers(HEADER_SIZE, len(other) + 1))
            data[at:] = other[cut:]
        else:  # replace a byte by a value tag
            data[min(at, len(data) - 1) if len(data) > HEADER_SIZE else at : at + 1] = bytes([b"n?ifsyAalmFI"[int(rng.integers(12))]])
    return bytes(data)


def random_value(rng: np.random.Generator, depth: int = 0):
    """A random value of any wire type (arrays of any dtype and shape included)."""
    pick = int(rng.integers(10 if depth < 2 else 8))
    if pick == 0:
        return None
    if pick == 1:
        return bool(rng.integers(2))
    if pick == 2:
        return int(rng.choice([0, 1, -1, 2**63 - 1, -(2**63), int(rng.integers(-1000, 1000))]))
    if pick == 3:
        return float(rng.choice([0.0, -0.0, 1e308, -1e308, 5e-324, np.nan, np.inf, -np.inf, rng.normal()]))
    if pick == 4:
        return str(rng.choice(["", "A0", "A0/cam0", "count", "refine", "\u00e9", "x" * 300]))
    if pick == 5:
        return rng.bytes(int(rng.choice([0, 6, 48, 96, 7])))
    if pick in (6, 7):
        dtype = rng.choice(["?", "<i1", "<i8", "<u8", "<f2", "<f4", "<f8"])
        shape = tuple(int(rng.choice([0, 1, 2, 3, 5])) for _ in range(int(rng.integers(0, 4))))
        arr = np.zeros(shape, dtype=dtype)
        if arr.size and arr.dtype.kind == "f":
            with np.errstate(all="ignore"):  # 1e308 overflows float16 to inf: wanted
                arr.flat[:] = rng.choice([np.nan, np.inf, 2.7, 5.9, 1e308, 0.0], size=arr.size)
        elif arr.size and arr.dtype.kind in "iu":
            arr.flat[:] = rng.integers(0, 100, size=arr.size)
        return arr
    if pick == 8:
        return tuple(random_value(rng, depth + 1) for _ in range(int(rng.integers(0, 4))))
    return {str(k): random_value(rng, depth + 1) for k in range(int(rng.integers(0, 3)))}


def _typed_frame(rng: np.random.Generator, cls: type, frame: bytes) -> bytes:
    """A frame of kind ``cls`` keeping the valid frame's header fields but with random field values."""
    from protocols.wire import payload_names

    names = payload_names(cls)
    out = [encode_str("A0"), encode_str("A1"), struct.pack("<q", int(rng.integers(-5, 5))), struct.pack("<H", len(names))]
    valid = cls.from_bytes(frame)
    for name in names:
        value = random_value(rng) if rng.random() < 0.5 else getattr(valid, name)
        if isinstance(value, np.ndarray) and rng.random() < 0.3:  # same array, other dtype (floats as ids)
            with np.errstate(all="ignore"):
                value = value.astype(rng.choice(["<f8", "<f4", "<u8", "?"]))
        encode_value(value, name, out)
    body = b"".join(out)
    return reseal(frame[:HEADER_SIZE] + body)


def _oversized_array_frame(rng: np.random.Generator, frame: bytes) -> bytes:
    """A frame whose first field is an array declaring huge (or zero-times-huge) dimensions."""
    ndim = int(rng.integers(1, 5))
    shape = [int(rng.choice([0, 1, 2**31, 2**32 - 1, int(rng.integers(2**32))])) for _ in range(ndim)]
    code = int(rng.integers(1, 13))
    tail = rng.bytes(int(rng.integers(0, 40)))
    body = frame[HEADER_SIZE:]
    head_len = 4 + 2 + 4 + 2 + 8 + 2  # sender, receiver ("A0", "A1"), round, field count
    arr = b"A" + struct.pack(f"<BB{ndim}I", code, ndim, *shape) + tail
    return reseal(frame[:HEADER_SIZE] + body[:head_len] + arr)


def hostile_frames(seed: int, count: int) -> Iterator[bytes]:
    """``count`` hostile frames drawn from ``seed`` (the issue's 76-byte frame first)."""
    rng = np.random.default_rng(seed)
    samples = [m.to_bytes() for m in sample_messages()]
    kinds = list(registered_kinds().values())
    yield ISSUE_FRAME
    for k in range(1, count):
        base = samples[int(rng.integers(len(samples)))]
        family = int(rng.integers(10))
        if family < 5:
            frame = _mutate(rng, base, samples)
            if rng.random() < 0.85:
                frame = reseal(frame.ljust(HEADER_SIZE, b"\0"))
        elif family < 8:
            cls = type(__import__("protocols.messages", fromlist=["decode"]).decode(base))
            frame = _typed_frame(rng, cls, base)
            if rng.random() < 0.2:  # the same body read as another kind
                frame = reseal(frame, kid=kind_id(kinds[int(rng.integers(len(kinds)))].KIND))
        elif family < 9:
            frame = _oversized_array_frame(rng, base)
        else:
            frame = rng.bytes(int(rng.integers(0, 80)))
            if rng.random() < 0.5:
                frame = reseal(base[:HEADER_SIZE] + frame, version=int(rng.choice([1, 2, 3])))
        yield frame
