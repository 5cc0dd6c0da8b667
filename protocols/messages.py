"""Typed, immutable messages and their versioned binary wire encoding.

Every message is a frozen, slotted, keyword-only dataclass deriving from :class:`Message`. It carries
``sender``, ``receiver`` (an agent name or :data:`BROADCAST`) and ``round``, plus the fields of its
kind. Encoding never uses pickle: numbers go through :mod:`struct`, arrays through
a fixed dtype code, the shape and the raw little-endian bytes, and the frame is checked with a CRC32.

Wire format, version 2 (all integers little-endian)::

    offset size  field
    0      4     magic  b"DCNT"
    4      1     version (2; version 1 frames are still read)
    5      1     flags (0, reserved)
    6      2     kind id: crc32(KIND) & 0xFFFF, unique in the registry
    8      4     body length B in bytes
    12     4     crc32 of bytes [0, 12) followed by the body
    16     B     body

    body := str(sender) str(receiver) i64(round) u16(field count) value*   (fields in declaration order)
    value := tag:u8 payload
        b"n" none | b"?" bool:u8 | b"i" int:i64 | b"f" float:f64 | b"s" str: u32 length + UTF-8
        b"y" bytes: u32 length + raw
        b"A" array (version 2): u8 dtype code + u8 ndim + u32 shape[ndim] + raw C-order little-endian data,
             codes 1..12 = bool, int8, int16, int32, int64, uint8, uint16, uint32, uint64, float16,
             float32, float64 (numeric or bool dtypes only)
        b"a" array (version 1 only): u32 length + .npy bytes (``np.save(..., allow_pickle=False)``);
             version 2 drops the ~128-byte .npy header per array
        b"l" tuple: u32 count + value* | b"m" mapping: u32 count + (str key, value)*
        b"F" tuple of floats: u32 count + f64* | b"I" tuple of ints: u32 count + i64*  (compact forms
        the encoder uses for non-empty homogeneous tuples of Python floats / ints)

A message's :attr:`Message.size_bytes` is exactly ``len(message.to_bytes())``. Two messages are equal
when their wire bytes are equal. Any defect in a buffer (short, bad magic, unknown version or kind,
checksum mismatch, malformed field, bad array) raises :class:`decentral.errors.ProtocolError`, never
another exception.

Adding a kind (other packages do this)::

    @register
    @dataclass(frozen=True, slots=True, eq=False, kw_only=True)
    class Gossip(Message):
        KIND: ClassVar[str] = "ensemble.gossip"
        values: np.ndarray

        def __post_init__(self):
            Message.__post_init__(self)
            _set(self, "values", as_array(self.values, "values", dtype=np.float64, ndim=1))

Supported field values: ``None``, ``bool``, ``int``, ``float``, ``str``, ``bytes``, numeric numpy
arrays, and tuples / string-keyed mappings of those (mappings are stored read-only, arrays are
stored as read-only copies).
"""

from __future__ import annotations

import dataclasses
import functools
import io
import math
import struct
import zlib
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, ClassVar

import numpy as np

from decentral.errors import ProtocolError

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

#: receiver marker of a message addressed to every other agent on the transport
BROADCAST = "*"
MAGIC = b"DCNT"
WIRE_VERSION = 2
_READABLE_VERSIONS = (1, 2)
#: dtype code on the wire (version 2) -> little-endian dtype
_DTYPES = {1: np.dtype("?"), 2: np.dtype("<i1"), 3: np.dtype("<i2"), 4: np.dtype("<i4"), 5: np.dtype("<i8"),
           6: np.dtype("<u1"), 7: np.dtype("<u2"), 8: np.dtype("<u4"), 9: np.dtype("<u8"), 10: np.dtype("<f2"),
           11: np.dtype("<f4"), 12: np.dtype("<f8")}
_DTYPE_CODES = {dt: code for code, dt in _DTYPES.items()}
_MAX_NDIM = 32
_HEADER = struct.Struct("<4sBBHII")
HEADER_SIZE = _HEADER.size  # 16
_MAX_NAME = 255

_REGISTRY: dict[int, type["Message"]] = {}


def kind_id(kind: str) -> int:
    """Return the 16-bit wire id of a kind name: ``crc32(kind) & 0xFFFF``."""
    return zlib.crc32(kind.encode("utf-8")) & 0xFFFF


def _set(obj: Any, name: str, value: Any) -> None:
    """Assign a field of a frozen dataclass during ``__post_init__``."""
    object.__setattr__(obj, name, value)


def as_array(
    value: Any,
    field: str,
    *,
    dtype: Any | None = None,
    ndim: int | None = None,
    shape: tuple[int | None, ...] | None = None,
) -> np.ndarray:
    """Return ``value`` as a read-only, C-contiguous copy, checked against ``dtype``/``ndim``/``shape``.

    Raises
    ------
    ProtocolError
        If ``value`` cannot be converted or has the wrong number of dimensions or shape.
    """
    try:
        raw = np.asarray(value)
    except (TypeError, ValueError, OverflowError) as err:
        raise ProtocolError(f"field {field!r}: not an array of {dtype}: {err}") from None
    if raw.size and raw.dtype.kind not in "biuf":  # never parse numbers out of strings or objects
        raise ProtocolError(f"field {field!r}: numbers expected, got dtype {raw.dtype}")
    if dtype is not None and np.dtype(dtype).kind in "iu":
        arr = _integer_array(raw, field, np.dtype(dtype))
    else:
        try:
            arr = np.array(raw, dtype=dtype, copy=True, order="C")
        except (TypeError, ValueError, OverflowError) as err:
            raise ProtocolError(f"field {field!r}: not an array of {dtype}: {err}") from None
    if arr.dtype.kind not in "biuf":
        raise ProtocolError(f"field {field!r}: dtype {arr.dtype} is not numeric or bool")
    if ndim is not None and arr.ndim != ndim:
        raise ProtocolError(f"field {field!r}: expected {ndim} dimensions, got shape {arr.shape}")
    if shape is not None:
        if arr.ndim != len(shape) or any(w is not None and w != s for w, s in zip(shape, arr.shape)):
            raise ProtocolError(f"field {field!r}: expected shape {shape}, got {arr.shape}")
    arr.setflags(write=False)
    return arr


def _integer_array(value: Any, field: str, dtype: np.dtype) -> np.ndarray:
    """``value`` as an integer array of ``dtype``: integers only (no floats, NaN or bools), in range.

    An empty sequence is accepted whatever its dtype (``[]`` is float64 to numpy).
    """
    raw = np.asarray(value)
    if raw.size and raw.dtype.kind not in "iu":
        raise ProtocolError(f"field {field!r}: integers expected, got dtype {raw.dtype}")
    if raw.size:
        info = np.iinfo(dtype)
        lo, hi = int(raw.min()), int(raw.max())
        if lo < info.min or hi > info.max:
            raise ProtocolError(f"field {field!r}: integer out of the {dtype} range")
    return np.array(raw, dtype=dtype, copy=True, order="C")


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


_SCALARS = (int, float, str, bool, bytes, type(None))


def _freeze(value: Any, field: str) -> Any:
    """Make a field value immutable (arrays read-only copies, mappings read-only, lists tuples)."""
    if type(value) in _SCALARS:
        return value
    if type(value) is tuple and all(type(v) in _SCALARS for v in value):
        return value
    if isinstance(value, np.ndarray):
        return as_array(value, field)
    if isinstance(value, Mapping):
        return MappingProxyType({str(k): _freeze(v, field) for k, v in value.items()})
    if isinstance(value, (list, tuple)):
        return tuple(_freeze(v, field) for v in value)
    return value


@functools.lru_cache(maxsize=None)
def _payload_names(cls: type) -> tuple[str, ...]:
    """Kind-specific field names of a message class, in wire order (cached per class)."""
    return tuple(f.name for f in dataclasses.fields(cls) if f.name not in ("sender", "receiver", "round"))


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
            if not isinstance(value, str) or not value or len(value.encode("utf-8")) > _MAX_NAME:
                raise ProtocolError(f"field {name!r}: must be a non-empty name of at most 255 bytes")
        if type(self.round) is not int:
            if isinstance(self.round, bool) or not isinstance(self.round, (int, np.integer)):
                raise ProtocolError(f"field 'round': must be an int, got {type(self.round).__name__}")
            _set(self, "round", int(self.round))
        if not -(2**63) <= self.round < 2**63:
            raise ProtocolError("field 'round': out of the signed 64-bit range")
        for name in _payload_names(type(self)):
            _set(self, name, _freeze(getattr(self, name), name))

    # ------------------------------------------------------------------ encoding
    @property
    def is_broadcast(self) -> bool:
        """Whether the message is addressed to every other agent."""
        return self.receiver == BROADCAST

    def payload_fields(self) -> tuple[str, ...]:
        """Names of the kind-specific fields, in wire order."""
        return _payload_names(type(self))

    def to_bytes(self) -> bytes:
        """Encode the message as one wire frame (see the module docstring)."""
        return self._encode(WIRE_VERSION)

    def _encode(self, version: int) -> bytes:
        """Encode as a frame of wire ``version`` (1 only for compatibility tests)."""
        cls = type(self)
        if _REGISTRY.get(kind_id(cls.KIND)) is not cls:
            raise ProtocolError(f"message class {cls.__name__} is not registered")
        out: list[bytes] = [_enc_str(self.sender), _enc_str(self.receiver), struct.pack("<q", self.round)]
        names = self.payload_fields()
        out.append(struct.pack("<H", len(names)))
        for name in names:
            _enc_value(getattr(self, name), name, out, version)
        body = b"".join(out)
        head = struct.pack("<4sBBHI", MAGIC, version, 0, kind_id(cls.KIND), len(body))
        crc = zlib.crc32(body, zlib.crc32(head))
        return head + struct.pack("<I", crc) + body

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
    other = _REGISTRY.get(kid)
    if other is not None and (other.KIND != cls.KIND or other.__qualname__ != cls.__qualname__):
        raise ProtocolError(f"kind {cls.KIND!r} collides with registered kind {other.KIND!r} (id {kid})")
    _REGISTRY[kid] = cls
    return cls


def registered_kinds() -> dict[str, type[Message]]:
    """Return kind name -> class for every registered kind."""
    return {c.KIND: c for c in _REGISTRY.values()}


# ---------------------------------------------------------------------------- value codec
def _enc_str(s: str) -> bytes:
    raw = s.encode("utf-8")
    return struct.pack("<I", len(raw)) + raw


def _enc_value(value: Any, field: str, out: list[bytes], version: int = WIRE_VERSION) -> None:
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
        out.append(b"s" + _enc_str(value))
    elif isinstance(value, bytes):
        out.append(b"y" + struct.pack("<I", len(value)) + value)
    elif isinstance(value, np.ndarray):
        if value.dtype.kind not in "biuf":
            raise ProtocolError(f"field {field!r}: dtype {value.dtype} cannot go on the wire")
        if version >= 2:
            code = _DTYPE_CODES.get(value.dtype.newbyteorder("<"))
            if code is None or value.ndim > _MAX_NDIM:
                raise ProtocolError(f"field {field!r}: dtype {value.dtype} / ndim {value.ndim} cannot go on the wire")
            data = np.ascontiguousarray(value, dtype=_DTYPES[code]).tobytes()
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
                _enc_value(item, field, out, version)
    elif isinstance(value, Mapping):
        out.append(b"m" + struct.pack("<I", len(value)))
        for key, item in value.items():
            if not isinstance(key, str):
                raise ProtocolError(f"field {field!r}: mapping keys must be str")
            out.append(_enc_str(key))
            _enc_value(item, field, out, version)
    else:
        raise ProtocolError(f"field {field!r}: values of type {type(value).__name__} cannot go on the wire")


_U8, _U16, _U32, _I64, _F64 = (struct.Struct(f) for f in ("<B", "<H", "<I", "<q", "<d"))


class CorruptFrame(ProtocolError):
    """A buffer that fails the framing checks (size, magic, version, length, checksum): damaged in
    transit or not a frame at all, as opposed to an intact frame whose body is malformed."""


class _Reader:
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
            return _load_array(self.take(self.num(_U32, field), field), field)
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
        dt = _DTYPES.get(code)
        if dt is None:
            raise ProtocolError(f"field {field!r}: bad array dtype code {code}")
        ndim = self.num(_U8, field)
        if ndim > _MAX_NDIM:
            raise ProtocolError(f"field {field!r}: bad array ndim {ndim}")
        shape = struct.unpack(f"<{ndim}I", self.take(4 * ndim, field))
        count = checked_shape(shape, dt.itemsize, field, self.end - self.pos)
        raw = self.take(count * dt.itemsize, field)
        arr = np.frombuffer(raw, dtype=dt).reshape(shape)
        if dt.kind == "b" and count and raw.strip(b"\x00\x01"):
            raise ProtocolError(f"field {field!r}: bad bool bytes in array")
        return arr.astype(dt.newbyteorder("="), copy=True)


def _load_array(raw: bytes, field: str) -> np.ndarray:
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


def decode(data: bytes | bytearray | memoryview) -> Message:
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
    magic, version, _flags, kid, length, crc = _HEADER.unpack_from(data)
    if magic != MAGIC:
        raise CorruptFrame(f"bad magic {magic!r}, expected {MAGIC!r}")
    if version not in _READABLE_VERSIONS:
        raise CorruptFrame(f"unsupported wire version {version}, this side reads {_READABLE_VERSIONS}")
    if len(data) != HEADER_SIZE + length:
        raise CorruptFrame(f"frame length mismatch: header says {length} body bytes, got {len(data) - HEADER_SIZE}")
    body = data[HEADER_SIZE:]
    if zlib.crc32(body, zlib.crc32(data[:12])) != crc:
        raise CorruptFrame("checksum mismatch: the frame is corrupted")
    cls = _REGISTRY.get(kid)
    if cls is None:
        raise ProtocolError(f"unknown message kind id {kid}")
    r = _Reader(body, version)
    sender = r.string("sender")
    receiver = r.string("receiver")
    rnd = r.num(_I64, "round")
    count = r.num(_U16, "field count")
    names = _payload_names(cls)
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


# ---------------------------------------------------------------------------- concrete kinds
def _finite_float(value: Any, field: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ProtocolError(f"field {field!r}: must be a number")
    value = float(value)
    if not math.isfinite(value):
        raise ProtocolError(f"field {field!r}: must be finite")
    return value


def _finite_array(value: Any, field: str, **kw: Any) -> np.ndarray:
    arr = as_array(value, field, dtype=np.float64, **kw)
    if not np.all(np.isfinite(arr)):
        raise ProtocolError(f"field {field!r}: must be finite")
    return arr


@register
@dataclass(frozen=True, slots=True, eq=False, kw_only=True)
class Tracks(Message):
    """One camera frame's identified node detections, shared with other agents.

    Attributes
    ----------
    t : float
        Time of the frame (s).
    camera : str
        Camera key ``"assembly/camera"`` as in ``decentral.log/1``.
    ids : ndarray, shape (n,), int64
        Node ids (unique within the frame).
    uvr : ndarray, shape (n, 3), float64
        Image centre ``(u, v)`` and radius ``r`` of each detection, pixels.
    """

    KIND: ClassVar[str] = "tracks"

    t: float
    camera: str
    ids: np.ndarray
    uvr: np.ndarray

    def __post_init__(self) -> None:
        Message.__post_init__(self)
        _set(self, "t", _finite_float(self.t, "t"))
        if not isinstance(self.camera, str) or "/" not in self.camera:
            raise ProtocolError("field 'camera': must be a key 'assembly/camera'")
        ids = as_array(self.ids, "ids", dtype=np.int64, ndim=1)
        _set(self, "ids", ids)
        _set(self, "uvr", _finite_array(self.uvr, "uvr", shape=(ids.shape[0], 3)))
        if len(np.unique(ids)) != len(ids):
            raise ProtocolError("field 'ids': duplicate node ids in one frame")


@register
@dataclass(frozen=True, slots=True, eq=False, kw_only=True)
class PoseEstimates(Message):
    """The sender's planar estimates of other agents relative to itself (Kanovsky §3).

    Attributes
    ----------
    t : float
        Time the estimates refer to (s).
    subjects : tuple of str, length n
        Names of the estimated agents (unique).
    poses : ndarray, shape (n, 3), float64
        ``(x, y, theta)`` of each subject's frame in the sender's frame at ``t`` (m, m, rad).
    covariances : ndarray, shape (n, 3, 3), float64
        Covariance of each pose, in the same order.
    """

    KIND: ClassVar[str] = "pose_estimates"

    t: float
    subjects: tuple[str, ...]
    poses: np.ndarray
    covariances: np.ndarray

    def __post_init__(self) -> None:
        Message.__post_init__(self)
        _set(self, "t", _finite_float(self.t, "t"))
        subjects = self.subjects
        if not isinstance(subjects, tuple) or not all(isinstance(s, str) and s for s in subjects):
            raise ProtocolError("field 'subjects': must be a tuple of names")
        if len(set(subjects)) != len(subjects):
            raise ProtocolError("field 'subjects': duplicate names")
        n = len(subjects)
        _set(self, "poses", _finite_array(self.poses, "poses", shape=(n, 3)))
        _set(self, "covariances", _finite_array(self.covariances, "covariances", shape=(n, 3, 3)))


def _blocks(value: Any, field: str) -> MappingProxyType:
    if not isinstance(value, Mapping):
        raise ProtocolError(f"field {field!r}: must map block names to float arrays")
    out = {}
    for key, arr in value.items():
        if not isinstance(key, str) or not key:
            raise ProtocolError(f"field {field!r}: block names must be non-empty str")
        out[key] = _finite_array(arr, f"{field}[{key}]")
    return MappingProxyType(out)


@register
@dataclass(frozen=True, slots=True, eq=False, kw_only=True)
class AdmmPrimal(Message):
    """An agent's local copies of shared variable blocks after its primal update.

    Attributes
    ----------
    window : int
        Id of the estimation window (sliding window of steps) the iteration belongs to.
    blocks : Mapping[str, ndarray]
        Block name -> finite float64 array (any shape). Names are agreed by the protocol that uses them.
    """

    KIND: ClassVar[str] = "admm.primal"

    window: int
    blocks: Mapping[str, np.ndarray]

    def __post_init__(self) -> None:
        Message.__post_init__(self)
        if isinstance(self.window, bool) or not isinstance(self.window, (int, np.integer)):
            raise ProtocolError("field 'window': must be an int")
        _set(self, "window", int(self.window))
        _set(self, "blocks", _blocks(self.blocks, "blocks"))


@register
@dataclass(frozen=True, slots=True, eq=False, kw_only=True)
class AdmmDual(Message):
    """Dual variables (scaled multipliers) of shared blocks, and the penalty they are scaled by.

    Attributes
    ----------
    window : int
        Estimation window id.
    blocks : Mapping[str, ndarray]
        Block name -> finite float64 array.
    rho : float
        Positive penalty parameter the duals refer to (so peers can follow penalty adaptation).
    """

    KIND: ClassVar[str] = "admm.dual"

    window: int
    blocks: Mapping[str, np.ndarray]
    rho: float = 1.0

    def __post_init__(self) -> None:
        Message.__post_init__(self)
        if isinstance(self.window, bool) or not isinstance(self.window, (int, np.integer)):
            raise ProtocolError("field 'window': must be an int")
        _set(self, "window", int(self.window))
        _set(self, "blocks", _blocks(self.blocks, "blocks"))
        rho = _finite_float(self.rho, "rho")
        if rho <= 0:
            raise ProtocolError("field 'rho': must be positive")
        _set(self, "rho", rho)


@register
@dataclass(frozen=True, slots=True, eq=False, kw_only=True)
class Heartbeat(Message):
    """A liveness beacon: the sender is up at time ``t`` and has reached ``round``."""

    KIND: ClassVar[str] = "heartbeat"

    t: float

    def __post_init__(self) -> None:
        Message.__post_init__(self)
        _set(self, "t", _finite_float(self.t, "t"))


@register
@dataclass(frozen=True, slots=True, eq=False, kw_only=True)
class OdometryReport(Message):
    """The sender's own planar motion over its last ``L`` steps, so peers can predict its pose.

    Repeating recent steps lets a receiver that lost a report recover the motion from the next one.

    Attributes
    ----------
    t : float
        Time at the end of step ``round`` (s).
    motions : ndarray, shape (L, 3), float64
        Row ``l`` is ``(dx, dy, dtheta)`` of step ``round - L + 1 + l``: the sender's root at the end
        of that step in its root frame at the previous step (Liu et al. 2024 eq. (6)).
    covariances : ndarray, shape (L, 3, 3), float64
        Noise covariance of each row of ``motions``.
    """

    KIND: ClassVar[str] = "odometry"

    t: float
    motions: np.ndarray
    covariances: np.ndarray

    def __post_init__(self) -> None:
        Message.__post_init__(self)
        _set(self, "t", _finite_float(self.t, "t"))
        motions = _finite_array(self.motions, "motions", ndim=2)
        if motions.shape[1] != 3 or motions.shape[0] < 1:
            raise ProtocolError(f"field 'motions': expected shape (L >= 1, 3), got {motions.shape}")
        _set(self, "motions", motions)
        _set(self, "covariances", _finite_array(self.covariances, "covariances", shape=(motions.shape[0], 3, 3)))

    @property
    def first_round(self) -> int:
        """Round of the first row of ``motions``."""
        return self.round - self.motions.shape[0] + 1
