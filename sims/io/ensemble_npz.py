"""Read and validate ``decentral.ensemble/1`` observations; write ensemble estimates (CONTRACT §3).

The reader never trusts the file: every array is checked for presence, type, shape and finiteness,
and the problem's invariants (ids in range, no self-observation, symmetric pairs) are checked by
:meth:`decentral.ensemble.EnsembleProblem.validate`. Any violation raises :class:`InputError`
naming the file and the field. NPZ files are loaded with ``allow_pickle=False``.
"""

from __future__ import annotations

import contextlib
import io
import os
import zipfile
from dataclasses import dataclass
from typing import Any

import numpy as np

from decentral.ensemble.problem import EnsembleEstimate, EnsembleProblem
from decentral.errors import InputError
from sims.io.atomic import write_atomic

__all__ = ["OBSERVATION_FORMAT", "ESTIMATE_FORMAT", "TRUTH_FORMAT", "EnsembleTruth", "read_ensemble",
           "read_ensemble_positions", "read_ensemble_truth", "write_ensemble_estimate", "is_npz"]

OBSERVATION_FORMAT = "decentral.ensemble/1"
#: ``format`` field written into estimates (the contract requires ``position`` and ``orientation``)
ESTIMATE_FORMAT = "decentral.ensemble_estimate/1"
#: ``format`` of the true poses that ``decentral make-ensemble --truth`` writes
TRUTH_FORMAT = "decentral.ensemble_truth/1"


def _scalar(data: Any, key: str, src: str) -> Any:
    if key not in data.files:
        raise InputError("missing", source=src, field=key)
    a = data[key]
    if a.size != 1:
        raise InputError(f"expected a single value, got shape {a.shape}", source=src, field=key)
    return a.reshape(()).item()


def _int_scalar(data: Any, key: str, src: str) -> int:
    v = _scalar(data, key, src)
    if isinstance(v, bool) or not isinstance(v, (int, np.integer, float, np.floating)):
        raise InputError(f"expected an integer, got {type(v).__name__}", source=src, field=key)
    if isinstance(v, (float, np.floating)) and not (np.isfinite(v) and float(v).is_integer()):
        raise InputError(f"expected an integer, got {v}", source=src, field=key)
    return int(v)


def _number(data: Any, key: str, src: str) -> float:
    v = _scalar(data, key, src)
    if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
        raise InputError(f"expected a number, got {type(v).__name__}", source=src, field=key)
    return float(v)


def _int_array(data: Any, key: str, src: str) -> np.ndarray:
    if key not in data.files:
        raise InputError("missing", source=src, field=key)
    a = data[key]
    if a.ndim != 1:
        raise InputError(f"expected a 1-D array, got shape {a.shape}", source=src, field=key)
    if a.dtype.kind in "iu":
        return a.astype(np.int64)
    if a.dtype.kind == "f":
        if not np.all(np.isfinite(a)):
            raise InputError("non-finite value", source=src, field=key)
        if not np.all(a == np.round(a)):
            raise InputError("ids must be integers", source=src, field=key)
        return a.astype(np.int64)
    raise InputError(f"expected integer ids, got dtype {a.dtype}", source=src, field=key)


def is_npz(path: str | os.PathLike) -> bool:
    """Whether ``path`` starts like a zip archive (an ``.npz``); False when it cannot be read."""
    try:
        with open(path, "rb") as fh:
            return fh.read(4) == b"PK\x03\x04"
    except OSError:
        return False


@contextlib.contextmanager
def _open_npz(path: str | os.PathLike):
    """``np.load`` without pickles; any read failure becomes an :class:`InputError` naming the file."""
    src = str(path)
    if os.path.isfile(src) and not is_npz(src):
        raise InputError("not an .npz archive", source=src)
    try:
        with np.load(src, allow_pickle=False) as data:
            if not isinstance(data, np.lib.npyio.NpzFile):
                raise InputError("not an .npz archive", source=src)
            yield data
    except InputError:
        raise
    except FileNotFoundError:
        raise InputError("file not found", source=src) from None
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as err:
        raise InputError(f"cannot read as .npz ({type(err).__name__}: {err})".splitlines()[0], source=src) from None


def _format(data: Any, expected: str, src: str, required: bool = True) -> None:
    if "format" not in data.files:
        if required:
            raise InputError("missing", source=src, field="format")
        return
    fmt = data["format"]
    if fmt.dtype.kind not in "US" or fmt.size != 1 or str(fmt.reshape(()).item()) != expected:
        shown = str(fmt.reshape(()).item()) if fmt.size == 1 else f"array of shape {fmt.shape}"
        raise InputError(f"expected {expected!r}, got {shown!r}", source=src, field="format")


def _points(data: Any, key: str, src: str, n: int | None = None, dim: int | None = None) -> np.ndarray:
    """A finite (n, dim) float array ``key``, dim 2 or 3."""
    if key not in data.files:
        raise InputError("missing", source=src, field=key)
    a = data[key]
    if a.dtype.kind not in "fiu" or a.ndim != 2 or a.shape[1] not in (2, 3):
        raise InputError(f"expected an (n, 2) or (n, 3) array of numbers, got {a.dtype} {a.shape}",
                         source=src, field=key)
    if (n is not None and a.shape[0] != n) or (dim is not None and a.shape[1] != dim):
        raise InputError(f"expected shape ({n}, {dim}), got {a.shape}", source=src, field=key)
    a = a.astype(float)
    if not np.all(np.isfinite(a)):
        raise InputError("non-finite value", source=src, field=key)
    return a


@dataclass(frozen=True)
class EnsembleTruth:
    """True module centres of an ensemble (``decentral.ensemble_truth/1``).

    Attributes
    ----------
    position : ndarray, shape (n, dim)
        True centres, metres.
    radius : float
        Module radius, metres.
    pairs : ndarray of int64, shape (P, 2), or None
        Observed neighbour pairs (``i < j``), when the file holds them.
    """

    position: np.ndarray
    radius: float
    pairs: np.ndarray | None


def read_ensemble_truth(path: str | os.PathLike) -> EnsembleTruth:
    """Load and validate a ``decentral.ensemble_truth/1`` file; raise :class:`InputError` on any defect."""
    src = str(path)
    with _open_npz(src) as data:
        _format(data, TRUTH_FORMAT, src)
        position = _points(data, "position", src)
        radius = _number(data, "radius", src)
        if not (np.isfinite(radius) and radius > 0):
            raise InputError(f"expected a positive number, got {radius!r}", source=src, field="radius")
        pairs = None
        if "pairs" in data.files:
            pairs = data["pairs"]
            n = position.shape[0]
            if pairs.dtype.kind not in "iu" or pairs.ndim != 2 or pairs.shape[1] != 2:
                raise InputError(f"expected a (P, 2) integer array, got {pairs.dtype} {pairs.shape}",
                                 source=src, field="pairs")
            if pairs.size and (pairs.min() < 0 or pairs.max() >= n or np.any(pairs[:, 0] == pairs[:, 1])):
                raise InputError(f"ids must be distinct and in 0..{n - 1}", source=src, field="pairs")
            pairs = pairs.astype(np.int64)
    return EnsembleTruth(position, float(radius), pairs)


def read_ensemble_positions(path: str | os.PathLike, n: int, dim: int) -> np.ndarray:
    """The ``position`` (n, dim) of an ensemble estimate ``.npz`` (its ``format``, if any, checked)."""
    src = str(path)
    with _open_npz(src) as data:
        _format(data, ESTIMATE_FORMAT, src, required=False)
        return _points(data, "position", src, n, dim)


def read_ensemble(path: str | os.PathLike) -> EnsembleProblem:
    """Load and validate a ``decentral.ensemble/1`` file; raise :class:`InputError` on any defect."""
    src = str(path)
    with _open_npz(src) as data:
        _format(data, OBSERVATION_FORMAT, src)
        dim = _int_scalar(data, "dim", src)
        n = _int_scalar(data, "n", src)
        radius_v = _number(data, "radius", src)
        i = _int_array(data, "i", src)
        j = _int_array(data, "j", src)
        if "z" not in data.files:
            raise InputError("missing", source=src, field="z")
        z = data["z"]
        if z.dtype.kind not in "fiu":
            raise InputError(f"expected numbers, got dtype {z.dtype}", source=src, field="z")
        z = z.astype(float)
    return EnsembleProblem.create(dim, n, float(radius_v), i, j, z, source=src)


def write_ensemble_estimate(path: str | os.PathLike, estimate: EnsembleEstimate, **extra: Any) -> None:
    """Write ``position`` (n, dim), ``orientation`` (angles or w, x, y, z quaternions), ``component``
    and any ``extra`` arrays to ``path`` as one ``.npz``, atomically (nothing is left on failure)."""
    arrays = {
        "format": np.array(ESTIMATE_FORMAT),
        "position": np.ascontiguousarray(estimate.position, dtype=float),
        "orientation": np.ascontiguousarray(estimate.orientation, dtype=float),
        "component": np.asarray(estimate.component, dtype=np.int64),
    }
    for k, v in extra.items():
        arrays[k] = np.asarray(v)
    for k, v in arrays.items():
        if v.dtype.kind == "f" and not np.all(np.isfinite(v)):
            raise ValueError(f"refusing to write non-finite {k}")
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    write_atomic(path, lambda fh: fh.write(buf.getvalue()), binary=True)
