"""Field validators of message kinds: read-only numeric arrays, finite numbers, frozen values, assignment in ``__post_init__``."""

from __future__ import annotations

import math
from collections.abc import Mapping
from types import MappingProxyType
from typing import Any

import numpy as np

from decentral.errors import ProtocolError

__all__ = ["as_array", "finite_array", "finite_float", "freeze", "integer_array", "set_field"]


def set_field(obj: Any, name: str, value: Any) -> None:
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
        arr = integer_array(raw, field, np.dtype(dtype))
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


def integer_array(value: Any, field: str, dtype: np.dtype) -> np.ndarray:
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


SCALARS = (int, float, str, bool, bytes, type(None))


def freeze(value: Any, field: str) -> Any:
    """Make a field value immutable (arrays read-only copies, mappings read-only, lists tuples)."""
    if type(value) in SCALARS:
        return value
    if type(value) is tuple and all(type(v) in SCALARS for v in value):
        return value
    if isinstance(value, np.ndarray):
        return as_array(value, field)
    if isinstance(value, Mapping):
        return MappingProxyType({str(k): freeze(v, field) for k, v in value.items()})
    if isinstance(value, (list, tuple)):
        return tuple(freeze(v, field) for v in value)
    return value


def finite_float(value: Any, field: str) -> float:
    """``value`` as a finite float; a bool, a non-number or a non-finite value raises :class:`ProtocolError`."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ProtocolError(f"field {field!r}: must be a number")
    value = float(value)
    if not math.isfinite(value):
        raise ProtocolError(f"field {field!r}: must be finite")
    return value


def finite_array(value: Any, field: str, **kw: Any) -> np.ndarray:
    """``value`` as a read-only float64 array (:func:`as_array` with ``kw``) of finite entries."""
    arr = as_array(value, field, dtype=np.float64, **kw)
    if not np.all(np.isfinite(arr)):
        raise ProtocolError(f"field {field!r}: must be finite")
    return arr
