"""The wire codec of every message: frame header, CRC, value encoding, the kind registry, and :func:`decode`.

A frame is a 16-byte header (magic, version, kind id, body length, CRC32) and a body of the sender,
receiver, round and the kind's fields as tagged values; docs/wire_format.md gives the layout byte by
byte. Message classes (:mod:`protocols.message_base`) encode through :func:`encode_frame`; any defect
in a buffer raises :class:`decentral.errors.ProtocolError` (framing defects as :class:`CorruptFrame`).
"""

from __future__ import annotations

import dataclasses
import functools
import io
import math
import struct
import zlib
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from decentral.errors import ProtocolError

if TYPE_CHECKING:
    from protocols.message_base import Message

__all__ = [
    "MAGIC",
    "WIRE_VERSION",
    "READABLE_VERSIONS",
    "HEADER",
    "HEADER_SIZE",
    "REGISTRY",
    "CorruptFrame",
    "Reader",
    "checked_shape",
    "decode",
    "encode_frame",
    "encode_str",
    "encode_value",
    "kind_id",
    "load_array",
    "payload_names",
]

MAGIC = b"DCNT"
WIRE_VERSION = 2
READABLE_VERSIONS = (1, 2)
#: dtype code on the wire (version 2) -> little-endian dtype
DTYPES = {1: np.dtype("?"), 2: np.dtype("<i1"), 3: np.dtype("<i2"), 4: np.dtype("<i4"), 5: np.dtype("<i8"),
           6: np.dtype("<u1"), 7: np.dtype("<u2"), 8: np.dtype("<u4"), 9: np.dtype("<u8"), 10: np.dtype("<f2"),
           11: np.dtype("<f4"), 12: np.dtype("<f8")}
DTYPE_CODES = {dt: code for code, dt in DTYPES.items()}
MAX_NDIM = 32
HEADER = struct.Struct("<4sBBHII")
HEADER_SIZE = HEADER.size  # 16

#: kind id -> registered message class (filled by :func:`protocols.message_base.register`)
REGISTRY: dict[int, type["Message"]] = {}


def kind_id(kind: str) -> int:
    """Return the 16-bit wire id of a kind name: ``crc32(kind) & 0xFFFF``."""
    return zlib.crc32(kind.encode("utf-8")) & 0xFFFF


def checked_shape(shape: tuple[int, ...], itemsize: int, field: str, available: int) -> int:
    """Element count of a declared array ``shape``, refusing shapes no frame of ``available`` bytes can hold.

    The data of a non-empty array must fit in ``available`` bytes; the product of the non-zero
    dimensions of an empty one must still be a size numpy can represent (a zero-element array of
    dimensions whose product overflows is refused here, not by ``reshape``).

    Raises
    ------
    ProtocolError
        If the shape is impossible for the bytes that follow it.
    """
    if any(d < 0 for d in shape):
        raise ProtocolError(f"field {field!r}: negative dimension in array shape {shape}")
    count = math.prod(shape)
    if count * itemsize > available:
        raise ProtocolError(f"field {field!r}: truncated body: array of shape {shape} needs more than the "
                            f"{available} bytes left")
    if math.prod(d for d in shape if d) * max(itemsize, 1) >= 2**62:
        raise ProtocolError(f"field {field!r}: array shape {shape} is too large")
    return count


@functools.lru_cache(maxsize=None)
def payload_names(cls: type) -> tuple[str, ...]:
    """Kind-specific field names of a message class, in wire order (cached per class)."""
    return tuple(f.name for f in dataclasses.fields(cls) if f.name not in ("sender", "receiver", "round"))


def encode_frame(msg: "Message", version: int = WIRE_VERSION) -> bytes:
    """Encode ``msg`` as one frame of wire ``version`` (1 only for compatibility tests)."""
    cls = type(msg)
    if REGISTRY.get(kind_id(cls.KIND)) is not cls:
        raise ProtocolError(f"message class {cls.__name__} is not registered")
    out: list[bytes] = [encode_str(msg.sender), encode_str(msg.receiver), struct.pack("<q", msg.round)]
    names = payload_names(cls)
    out.append(struct.pack("<H", len(names)))
    for name in names:
        encode_value(getattr(msg, name), name, out, version)
    body = b"".join(out)
    head = struct.pack("<4sBBHI", MAGIC, version, 0, kind_id(cls.KIND), len(body))
    crc = zlib.crc32(body, zlib.crc32(head))
    return head + struct.pack("<I", crc) + body


def encode_str(s: str) -> bytes:
    raw = s.encode("utf-8")
    return struct.pack("<I", len(raw)) + raw


def encode_value(value: Any, field: str, out: list[bytes], version: int = WIRE_VERSION) -> None:
    if value is None:
        out.append(b"n")
    elif isinstance(value, (bool, np.bool_)):
        out.append(b"?" + struct.pack("<B", int(bool(value))))
    elif isinstance(value, (int, np.integer)):
        if not -(2**63) <= int(value) < 2**63:
            raise ProtocolError(f"field {field!r}: int out of the signed 64-bit range")
        out.append(b"i" + struct.pack("<q", int(value)))
    elif isinstance(value, (float, np.floating)):
        out.append(b"f" + struct.pack("<d", float(value)))
    elif isinstance(value, str):
        out.append(b"s" + encode_str(value))
    elif isinstance(value, bytes):
        out.append(b"y" + struct.pack("<I", len(value)) + value)
    elif isinstance(value, np.ndarray):
        if value.dtype.kind not in "biuf":
            raise ProtocolError(f"field {field!r}: dtype {value.dtype} cannot go on the wire")
        if version >= 2:
            code = DTYPE_CODES.get(value.dtype.newbyteorder("<"))
            if code is None or value.ndim > MAX_NDIM:
                raise ProtocolError(f"field {field!r}: dtype {value.dtype} / ndim {value.ndim} cannot go on the wire")
            data = np.ascontiguousarray(value, dtype=DTYPES[code]).tobytes()
            out.append(b"A" + struct.pack(f"<BB{value.ndim}I", code, value.ndim, *value.shape) + data)
            return
        buf = io.BytesIO()
        np.save(buf, value, allow_pickle=False)
        raw = buf.getvalue()
        out.append(b"a" + struct.pack("<I", len(raw)) + raw)
    elif isinstance(value, tuple):
        if value and all(type(v) is float for v in value):
            out.append(b"F" + _U32.pack(len(value)) + struct.pack(f"<{len(value)}d", *value))
        elif value and all(type(v) is int for v in value) and all(-(2**63) <= v < 2**63 for v in value):
            out.append(b"I" + _U32.pack(len(value)) + struct.pack(f"<{len(value)}q", *value))
        else:
            out.append(b"l" + _U32.pack(len(value)))
            for item in value:
                encode_value(item, field, out, version)
    elif isinstance(value, Mapping):
        out.append(b"m" + struct.pack("<I", len(value)))
        for key, item in value.items():
            if not isinstance(key, str):
                raise ProtocolError(f"field {field!r}: mapping keys must be str")
            out.append(encode_str(key))
            encode_value(item, field, out, version)
    else:
        raise ProtocolError(f"field {field!r}: values of type {type(value).__name__} cannot go on the wire")


_U8, _U16, _U32, _I64, _F64 = (struct.Struct(f) for f in ("<B", "<H", "<I", "<q", "<d"))


class CorruptFrame(ProtocolError):
    """A buffer that fails the framing checks (size, magic, version, length, checksum): damaged in
    transit or not a frame at all, as opposed to an intact frame whose body is malformed."""


class Reader:
    """Bounds-checked cursor over a body; every defect is a ProtocolError."""

    __slots__ = ("data", "pos", "end", "version")

    def __init__(self, data: bytes, version: int = WIRE_VERSION):
        self.data = data
        self.pos = 0
        self.end = len(data)
        self.version = version

    def take(self, n: int, what: str) -> bytes:
        if n < 0 or self.pos + n > self.end:
            raise ProtocolError(f"truncated body while reading {what}")
        chunk = self.data[self.pos : self.pos + n]
        self.pos += n
        return chunk

    def num(self, st: struct.Struct, what: str):
        if self.pos + st.size > self.end:
            raise ProtocolError(f"truncated body while reading {what}")
        (v,) = st.unpack_from(self.data, self.pos)
        self.pos += st.size
        return v

    def unpack(self, fmt: str, what: str) -> tuple:
        return struct.unpack(fmt, self.take(struct.calcsize(fmt), what))

    def string(self, what: str) -> str:
        n = self.num(_U32, what)
        try:
            return self.take(n, what).decode("utf-8")
        except UnicodeDecodeError:
            raise ProtocolError(f"{what}: invalid UTF-8") from None

    def value(self, field: str, depth: int = 0) -> Any:
        if depth > 16:
            raise ProtocolError(f"field {field!r}: nested too deeply")
        if self.pos >= self.end:
            raise ProtocolError(f"truncated body while reading field {field!r}")
        tag = self.data[self.pos : self.pos + 1]
        self.pos += 1
        if tag == b"f":
            return self.num(_F64, field)
        if tag == b"i":
            return self.num(_I64, field)
        if tag == b"F" or tag == b"I":
            n = self.num(_U32, field)
            raw = self.take(8 * n, field)
            return struct.unpack(f"<{n}{'d' if tag == b'F' else 'q'}", raw)
        if tag == b"n":
            return None
        if tag == b"?":
            b = self.num(_U8, field)
            if b > 1:
                raise ProtocolError(f"field {field!r}: bad bool byte {b}")
            return bool(b)
        if tag == b"s":
            return self.string(f"field {field!r}")
        if tag == b"y":
            return self.take(self.num(_U32, field), field)
        if tag == b"A" and self.version >= 2:
            return self.raw_array(field)
        if tag == b"a" and self.version == 1:
            return load_array(self.take(self.num(_U32, field), field), field)
        if tag == b"l":
            n = self.num(_U32, field)
            if n > self.end - self.pos:  # every value takes at least one byte
                raise ProtocolError(f"truncated body while reading field {field!r}")
            return tuple(self.value(field, depth + 1) for _ in range(n))
        if tag == b"m":
            n = self.num(_U32, field)
            if n > self.end - self.pos:
                raise ProtocolError(f"truncated body while reading field {field!r}")
            out = {}
            for _ in range(n):
                key = self.string(f"field {field!r} key")
                out[key] = self.value(field, depth + 1)
            return out
        raise ProtocolError(f"field {field!r}: unknown value tag {tag!r}")


    def raw_array(self, field: str) -> np.ndarray:
        code = self.num(_U8, field)
        dt = DTYPES.get(code)
        if dt is None:
            raise ProtocolError(f"field {field!r}: bad array dtype code {code}")
        ndim = self.num(_U8, field)
        if ndim > MAX_NDIM:
            raise ProtocolError(f"field {field!r}: bad array ndim {ndim}")
        shape = struct.unpack(f"<{ndim}I", self.take(4 * ndim, field))
        count = checked_shape(shape, dt.itemsize, field, self.end - self.pos)
        raw = self.take(count * dt.itemsize, field)
        arr = np.frombuffer(raw, dtype=dt).reshape(shape)
        if dt.kind == "b" and count and raw.strip(b"\x00\x01"):
            raise ProtocolError(f"field {field!r}: bad bool bytes in array")
        return arr.astype(dt.newbyteorder("="), copy=True)


def load_array(raw: bytes, field: str) -> np.ndarray:
    buf = io.BytesIO(raw)
    try:
        readers = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}
        version = np.lib.format.read_magic(buf)
        if version not in readers:
            raise ValueError(f".npy format version {version} is not read here")
        shape, _, dtype = readers[version](buf)
        checked_shape(shape, dtype.itemsize, field, len(raw) - buf.tell())
        buf.seek(0)
        arr = np.load(buf, allow_pickle=False)
    except Exception as err:  # numpy raises several types on malformed .npy data
        raise ProtocolError(f"field {field!r}: bad array ({type(err).__name__}: {err})") from None
    if not isinstance(arr, np.ndarray) or arr.dtype.kind not in "biuf":
        raise ProtocolError(f"field {field!r}: bad array dtype")
    return arr


def decode(data: bytes | bytearray | memoryview) -> "Message":
    """Decode one wire frame into a message of its registered kind.

    Parameters
    ----------
    data : bytes
        Exactly one frame, as produced by :meth:`Message.to_bytes`.

    Raises
    ------
    ProtocolError
        On a short buffer, bad magic, unknown version, length or checksum mismatch (these as its
        subclass :class:`CorruptFrame`), unknown kind, malformed or missing field, trailing bytes,
        array shapes the body cannot hold, or field values the kind rejects. Never another exception.
    """
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise ProtocolError(f"cannot decode a {type(data).__name__}, expected bytes")
    data = bytes(data)
    if len(data) < HEADER_SIZE:
        raise CorruptFrame(f"truncated frame: {len(data)} bytes, the header alone is {HEADER_SIZE}")
    magic, version, _flags, kid, length, crc = HEADER.unpack_from(data)
    if magic != MAGIC:
        raise CorruptFrame(f"bad magic {magic!r}, expected {MAGIC!r}")
    if version not in READABLE_VERSIONS:
        raise CorruptFrame(f"unsupported wire version {version}, this side reads {READABLE_VERSIONS}")
    if len(data) != HEADER_SIZE + length:
        raise CorruptFrame(f"frame length mismatch: header says {length} body bytes, got {len(data) - HEADER_SIZE}")
    body = data[HEADER_SIZE:]
    if zlib.crc32(body, zlib.crc32(data[:12])) != crc:
        raise CorruptFrame("checksum mismatch: the frame is corrupted")
    cls = REGISTRY.get(kid)
    if cls is None:
        raise ProtocolError(f"unknown message kind id {kid}")
    r = Reader(body, version)
    sender = r.string("sender")
    receiver = r.string("receiver")
    rnd = r.num(_I64, "round")
    count = r.num(_U16, "field count")
    names = payload_names(cls)
    if count != len(names):
        raise ProtocolError(f"{cls.KIND!r} frame has {count} fields, this version expects {len(names)}")
    values = {name: r.value(name) for name in names}
    if r.pos != len(body):
        raise ProtocolError(f"{len(body) - r.pos} trailing bytes after the last field")
    try:
        return cls(sender=sender, receiver=receiver, round=rnd, **values)
    except ProtocolError:
        raise
    except Exception as err:  # a kind's own validation must not leak other exception types
        raise ProtocolError(f"{cls.KIND!r} rejected its fields: {type(err).__name__}: {err}") from None
