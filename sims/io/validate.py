"""Small validators that turn raw JSON/NPZ values into arrays or raise :class:`InputError`.

Every function takes the value, the field path (for the message) and returns a clean value; the
caller attributes the error to its file with :meth:`InputError.located`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from decentral.errors import InputError

__all__ = [
    "require_mapping",
    "require_list",
    "require_number",
    "require_positive",
    "require_int",
    "require_vector",
    "require_matrix",
    "require_rotation",
]


def require_mapping(value: Any, field: str) -> dict:
    if not isinstance(value, dict):
        raise InputError(f"expected an object, got {type(value).__name__}", field=field)
    return value


def require_list(value: Any, field: str) -> list:
    if not isinstance(value, list):
        raise InputError(f"expected a list, got {type(value).__name__}", field=field)
    return value


def require_number(value: Any, field: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError(f"expected a number, got {type(value).__name__}", field=field)
    if not math.isfinite(value):
        raise InputError("must be finite", field=field)
    return float(value)


def require_positive(value: Any, field: str) -> float:
    number = require_number(value, field)
    if number <= 0:
        raise InputError(f"must be positive, got {number:g}", field=field)
    return number


def require_int(value: Any, field: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        if isinstance(value, float) and value.is_integer():
            return int(value)
        if isinstance(value, str):
            try:
                return int(value)
            except ValueError:
                pass
        raise InputError(f"expected an integer, got {value!r}", field=field)
    return value


def require_vector(value: Any, field: str, length: int) -> np.ndarray:
    items = require_list(value, field)
    if len(items) != length:
        raise InputError(f"expected {length} numbers, got {len(items)}", field=field)
    return np.array([require_number(x, f"{field}[{k}]") for k, x in enumerate(items)])


def require_matrix(value: Any, field: str, rows: int, cols: int) -> np.ndarray:
    items = require_list(value, field)
    if len(items) != rows:
        raise InputError(f"expected a {rows}x{cols} matrix, got {len(items)} rows", field=field)
    return np.vstack([require_vector(row, f"{field}[{k}]", cols) for k, row in enumerate(items)])


def require_rotation(value: Any, field: str, tol: float = 1e-6) -> np.ndarray:
    """A 3x3 rotation matrix: orthonormal to ``tol`` and with determinant +1."""
    R = require_matrix(value, field, 3, 3)
    if np.abs(R.T @ R - np.eye(3)).max() > tol or np.linalg.det(R) < 0:
        raise InputError("is not a 3x3 rotation matrix (R^T R != I or det != +1)", field=field)
    return R
