"""The input shape of an ONNX model, read from the file itself (no ``onnx`` package, no runtime).

An ONNX file is a protocol-buffer ``ModelProto``; its graph (field 7) lists the inputs (field 11,
``ValueInfoProto``: name 1, type 2 -> ``tensor_type`` 1 -> shape 2 -> ``dim`` 1, each a
``dim_value`` 1 (int) or a ``dim_param`` 2 (a name, e.g. ``"batch"``)). Only those fields are
decoded; the rest of the file is skipped by its wire types. This lets a detector take its input
size from the network it loads, whichever backend runs it.
"""

from __future__ import annotations

import os
from pathlib import Path

from decentral.errors import InputError

__all__ = ["onnx_input_shape"]


def _varint(buf: bytes, i: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        if i >= len(buf):
            raise ValueError("truncated varint")
        b = buf[i]
        i += 1
        value |= (b & 0x7F) << shift
        if b < 0x80:
            return value, i
        shift += 7
        if shift > 63:
            raise ValueError("varint too long")


def _fields(buf: bytes):
    """(field number, wire type, value) of one message: ints for varints, bytes for length-delimited."""
    i = 0
    while i < len(buf):
        key, i = _varint(buf, i)
        field, wire = key >> 3, key & 7
        if wire == 0:
            value, i = _varint(buf, i)
        elif wire == 1:
            value, i = buf[i:i + 8], i + 8
        elif wire == 2:
            n, i = _varint(buf, i)
            if i + n > len(buf):
                raise ValueError("truncated field")
            value, i = buf[i:i + n], i + n
        elif wire == 5:
            value, i = buf[i:i + 4], i + 4
        else:
            raise ValueError(f"unsupported wire type {wire}")
        yield field, wire, value


def _first(buf: bytes, field: int) -> bytes | None:
    return next((v for f, w, v in _fields(buf) if f == field and w == 2), None)


def onnx_input_shape(path: str | os.PathLike) -> tuple[int | None, ...]:
    """The first graph input's shape: one int per fixed dimension, None for a named (dynamic) one.

    Parameters
    ----------
    path : path
        An ONNX model file.

    Returns
    -------
    tuple
        E.g. ``(1, 3, 288, 384)`` for a network taking one 384 x 288 colour frame (N, C, H, W).

    Raises
    ------
    InputError
        When the file cannot be read or holds no input with a tensor shape.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
        graph = _first(data, 7)
        inputs = [v for f, w, v in _fields(graph) if f == 11 and w == 2] if graph is not None else []
        tensor = shape = None
        if inputs:
            typ = _first(inputs[0], 2)
            tensor = _first(typ, 1) if typ is not None else None
            shape = _first(tensor, 2) if tensor is not None else None
        if shape is None:
            raise ValueError("no input with a tensor shape")
        dims: list[int | None] = []
        for f, w, dim in _fields(shape):
            if f != 1 or w != 2:
                continue
            value = next((v for g, x, v in _fields(dim) if g == 1 and x == 0), None)
            dims.append(value)
    except OSError as exc:
        raise InputError(f"cannot read the ONNX model ({exc.strerror})", source=str(path)) from None
    except ValueError as exc:
        raise InputError(f"not an ONNX model ({exc})", source=str(path)) from None
    return tuple(dims)
