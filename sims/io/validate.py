"""Small validators that turn raw JSON/NPZ values into arrays or raise :class:`InputError`.

Every function takes the value, the field path (for the message) and returns a clean value; the
caller attributes the error to its file with :meth:`InputError.located`.
"""

from __future__ import annotations

import difflib
import math
import re
from typing import Any, Iterable

import numpy as np

from decentral.errors import InputError

__all__ = [
    "MAX_METRES",
    "MIN_METRES",
    "MAX_PIXELS",
    "MIN_PIXELS",
    "MAX_ANGLE",
    "MAX_SECONDS",
    "MAX_ID",
    "unknown_name",
    "require_mapping",
    "require_list",
    "require_number",
    "require_range",
    "require_positive",
    "require_int",
    "require_int_key",
    "require_vector",
    "require_matrix",
    "require_rotation",
]

# Physical ranges: finite values outside them are broken files, not robots, and are refused here by
# field rather than by a solver failing (or overflowing to inf) later.
#: largest magnitude of a length, metres (node centres, mounts, odometry steps, estimated positions)
MAX_METRES = 1e6
#: smallest positive length, metres (node and module radii)
MIN_METRES = 1e-6
#: largest magnitude of an image quantity, pixels (centres, radii, focal lengths, principal points)
MAX_PIXELS = 1e7
#: smallest positive image radius or focal length, pixels
MIN_PIXELS = 1e-3
#: largest magnitude of an angle, radians
MAX_ANGLE = 1e3
#: largest magnitude of a time stamp, seconds (Unix time in seconds is about 2e9)
MAX_SECONDS = 1e12
#: node and tag ids are integers of magnitude below 2**53 (exact in every JSON reader)
MAX_ID = 2**53

_DECIMAL = re.compile(r"-?[0-9]{1,16}")


def unknown_name(name: str, known: Iterable[str], what: str, field: str | None = None) -> InputError:
    """The error for an unknown key, option or parameter ``name``: the closest known name, then all of them.

    ``what`` says what was not known (``unknown key``); ``field`` defaults to ``name``. Returned, not
    raised, so that the caller's ``raise`` stays visible.

    Examples
    --------
    >>> str(unknown_name("n_assembly", ["n_assemblies", "steps"], "unknown key"))
    'n_assembly: unknown key (n_assembly: did you mean n_assemblies?); known: n_assemblies, steps'
    """
    known = sorted(set(known))
    close = difflib.get_close_matches(name, known, n=1, cutoff=0.6)
    hint = f" ({name}: did you mean {close[0]}?)" if close else ""
    return InputError(f"{what}{hint}; known: {', '.join(known)}", field=name if field is None else field)


def require_mapping(value: Any, field: str) -> dict:
    if not isinstance(value, dict):
        raise InputError(f"expected an object, got {type(value).__name__}", field=field)
    return value


def require_list(value: Any, field: str) -> list:
    if not isinstance(value, list):
        raise InputError(f"expected a list, got {type(value).__name__}", field=field)
    return value


def require_number(value: Any, field: str, bound: float | None = None) -> float:
    """A finite JSON number (not a bool); with ``bound``, of magnitude at most ``bound``."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError(f"expected a number, got {type(value).__name__}", field=field)
    if isinstance(value, int) and abs(value) > 2**1023:
        raise InputError("number out of range", field=field)
    if not math.isfinite(value):
        raise InputError("must be finite", field=field)
    if bound is not None and abs(value) > bound:
        raise InputError(f"magnitude {abs(value):.4g} is beyond the physical range (at most {bound:g})", field=field)
    return float(value)


def require_range(value: Any, field: str, lo: float, hi: float) -> float:
    """A finite number in ``[lo, hi]``."""
    number = require_number(value, field)
    if not lo <= number <= hi:
        raise InputError(f"must be in [{lo:g}, {hi:g}], got {number:.4g}", field=field)
    return number


def require_positive(value: Any, field: str, lo: float = 0.0, hi: float = math.inf) -> float:
    """A number ``> 0`` (and, with bounds, in ``[lo, hi]``)."""
    number = require_number(value, field)
    if number <= 0:
        raise InputError(f"must be positive, got {number:g}", field=field)
    if not lo <= number <= hi:
        raise InputError(f"must be in [{lo:g}, {hi:g}], got {number:.4g}", field=field)
    return number


def require_int(value: Any, field: str) -> int:
    """A JSON integer (not a bool, a float or a string) of magnitude below :data:`MAX_ID`."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise InputError(f"expected an integer, got {value!r}"[:120], field=field)
    if abs(value) >= MAX_ID:
        raise InputError(f"integer {value} is out of range (magnitude below 2**53)", field=field)
    return value


def require_int_key(key: str, field: str) -> int:
    """An integer given as a JSON object key: a decimal-integer string such as ``"5"`` or ``"-2"``."""
    if not isinstance(key, str) or not _DECIMAL.fullmatch(key):
        raise InputError(f"expected a decimal integer key, got {key!r}"[:120], field=field)
    return require_int(int(key), field)


def require_vector(value: Any, field: str, length: int, bound: float | None = None) -> np.ndarray:
    """A list of ``length`` finite numbers (each of magnitude at most ``bound`` when given)."""
    items = require_list(value, field)
    if len(items) != length:
        raise InputError(f"expected {length} numbers, got {len(items)}", field=field)
    return np.array([require_number(x, f"{field}[{k}]", bound) for k, x in enumerate(items)])


def require_matrix(value: Any, field: str, rows: int, cols: int, bound: float | None = None) -> np.ndarray:
    """A list of ``rows`` lists of ``cols`` finite numbers."""
    items = require_list(value, field)
    if len(items) != rows:
        raise InputError(f"expected a {rows}x{cols} matrix, got {len(items)} rows", field=field)
    return np.vstack([require_vector(row, f"{field}[{k}]", cols, bound) for k, row in enumerate(items)])


def require_rotation(value: Any, field: str, tol: float = 1e-6) -> np.ndarray:
    """A 3x3 rotation matrix: orthonormal to ``tol`` and with determinant +1."""
    R = require_matrix(value, field, 3, 3, bound=2.0)
    if np.abs(R.T @ R - np.eye(3)).max() > tol or np.linalg.det(R) < 0:
        raise InputError("is not a 3x3 rotation matrix (R^T R != I or det != +1)", field=field)
    return R
