"""Read and validate ``decentral.ensemble/1`` observations; write ensemble estimates (docs/formats.md).

The reader never trusts the file: every array is checked for presence, type, shape and finiteness,
and the problem's invariants (ids in range, no self-observation, symmetric pairs) are checked by
:meth:`decentral.ensemble.EnsembleProblem.validate`. Any violation raises :class:`InputError`
naming the file and the field. Arrays are read member by member from the zip, never unpickled,
and only after their declared shapes passed the limits of :mod:`sims.io.limits`.
"""

from __future__ import annotations

import io
import math
import os
import zipfile
import zlib
from dataclasses import dataclass
from typing import Any

import numpy as np

from decentral.ensemble.problem import MAX_RADIUS, MIN_RADIUS, EnsembleEstimate, EnsembleProblem
from decentral.errors import InputError, SolverError
from sims.io.atomic import write_atomic
from sims.io.kinds import require_kind
from sims.io.limits import Limits, current_limits, over_limit
from sims.io.validate import MAX_METRES

__all__ = ["OBSERVATION_FORMAT", "ESTIMATE_FORMAT", "TRUTH_FORMAT", "EnsembleTruth", "read_npz_arrays", "read_ensemble",
           "read_ensemble_positions", "read_ensemble_truth", "write_ensemble_estimate", "is_npz"]

OBSERVATION_FORMAT = "decentral.ensemble/1"
#: ``format`` field written into estimates (the contract requires ``position`` and ``orientation``)
ESTIMATE_FORMAT = "decentral.ensemble_estimate/1"
#: ``format`` of the true poses that ``decentral make-ensemble --truth`` writes
TRUTH_FORMAT = "decentral.ensemble_truth/1"


def _npy_header(fh: Any, key: str, src: str) -> tuple[tuple[int, ...], bool, np.dtype]:
    """Shape, Fortran order and dtype declared by the ``.npy`` header at the start of ``fh``."""
    readers = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}
    try:
        version = np.lib.format.read_magic(fh)
        if version not in readers:
            raise ValueError(f"unsupported .npy version {version}")
        return readers[version](fh)
    except ValueError as err:
        raise InputError(f"not a valid .npy array ({err})".splitlines()[0], source=src, field=key) from None


def read_npz_arrays(path: str | os.PathLike, limits: Limits | None = None) -> dict[str, np.ndarray]:
    """Every array of the ``.npz`` at ``path``, checked against ``limits`` before anything is allocated.

    Each member's size comes from the zip directory and its shape and dtype from its ``.npy``
    header; the declared shape must account for exactly the member's bytes, the total must stay
    within ``limits.max_array_mb``, and object (pickled) arrays are refused. A member whose data
    inflates to more than its directory entry says fails its checksum, since no more than the
    declared bytes are ever read.

    Raises
    ------
    InputError
        Naming the file (and the member as the field) on any defect or exceeded limit.
    """
    limits = limits or current_limits()
    src = str(path)
    budget = limits.max_array_mb * 1e6
    try:
        if not zipfile.is_zipfile(src):
            raise InputError("not an .npz archive (a zip of .npy arrays)", source=src)
        arrays = {}
        with zipfile.ZipFile(src) as archive:
            members = [m for m in archive.infolist() if m.filename.endswith(".npy")]
            total = sum(m.file_size for m in members)
            if total > budget:
                raise over_limit("decompressed size", round(total / 1e6, 1), "max_array_mb", limits.max_array_mb,
                                 " MB", source=src)
            for member in members:
                key = member.filename[:-4]
                with archive.open(member) as fh:
                    shape, fortran, dtype = _npy_header(fh, key, src)
                    if dtype.hasobject or dtype.kind not in "biufUS":
                        raise InputError(f"dtype {dtype} is not a plain number or string array", source=src, field=key)
                    nbytes = math.prod(shape) * dtype.itemsize
                    if nbytes != member.file_size - fh.tell():
                        raise InputError(f"header declares shape {shape} ({nbytes} bytes) but the member holds "
                                         f"{member.file_size - fh.tell()} bytes", source=src, field=key)
                    data = fh.read(nbytes)
                    fh.read(1)  # reaching the end verifies the member's CRC
                arrays[key] = np.frombuffer(data, dtype=dtype).reshape(shape, order="F" if fortran else "C")
        return arrays
    except FileNotFoundError:
        raise InputError("file not found", source=src) from None
    except IsADirectoryError:
        raise InputError("is a directory, not a file", source=src) from None
    except (OSError, ValueError, zipfile.BadZipFile, EOFError, zlib.error, NotImplementedError) as err:
        raise InputError(f"cannot read as .npz ({type(err).__name__}: {err})".splitlines()[0], source=src) from None


def _scalar(data: dict, key: str, src: str) -> Any:
    if key not in data:
        raise InputError("missing", source=src, field=key)
    a = data[key]
    if a.size != 1:
        raise InputError(f"expected a single value, got shape {a.shape}", source=src, field=key)
    return a.reshape(()).item()


def _int_scalar(data: dict, key: str, src: str) -> int:
    v = _scalar(data, key, src)
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise InputError(f"expected an integer, got {type(v).__name__}", source=src, field=key)
    if isinstance(v, float) and not (np.isfinite(v) and v.is_integer()):
        raise InputError(f"expected an integer, got {v}", source=src, field=key)
    return int(v)


#: float id arrays must hold integers exactly representable in float64
_MAX_FLOAT_ID = 2.0**53


def _int_array(data: dict, key: str, src: str) -> np.ndarray:
    if key not in data:
        raise InputError("missing", source=src, field=key)
    a = data[key]
    if a.ndim != 1:
        raise InputError(f"expected a 1-D array, got shape {a.shape}", source=src, field=key)
    if a.dtype.kind == "u" and a.size and int(a.max()) >= 2**63:
        raise InputError(f"id {int(a.max())} is out of range", source=src, field=key)
    if a.dtype.kind in "iu":
        return a.astype(np.int64)
    if a.dtype.kind == "f":
        if not np.all(np.isfinite(a)):
            raise InputError("non-finite value", source=src, field=key)
        if not np.all(a == np.round(a)) or (a.size and np.abs(a).max() >= _MAX_FLOAT_ID):
            raise InputError("ids must be integers", source=src, field=key)
        return a.astype(np.int64)
    raise InputError(f"expected integer ids, got dtype {a.dtype}", source=src, field=key)


def _number(data: dict, key: str, src: str) -> float:
    v = _scalar(data, key, src)
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise InputError(f"expected a number, got {type(v).__name__}", source=src, field=key)
    return float(v)


def is_npz(path: str | os.PathLike) -> bool:
    """Whether ``path`` starts like a zip archive (an ``.npz``); False when it cannot be read."""
    try:
        with open(path, "rb") as fh:
            return fh.read(4) == b"PK\x03\x04"
    except OSError:
        return False


def _format(data: dict, expected: str, src: str, required: bool = True) -> None:
    if "format" not in data:
        if required:
            raise InputError("missing", source=src, field="format")
        return
    fmt = data["format"]
    if fmt.dtype.kind not in "US" or fmt.size != 1 or str(fmt.reshape(()).item()) != expected:
        shown = str(fmt.reshape(()).item()) if fmt.size == 1 else f"array of shape {fmt.shape}"
        raise InputError(f"expected {expected!r}, got {shown!r}", source=src, field="format")


def _points(data: dict, key: str, src: str, n: int | None = None, dim: int | None = None) -> np.ndarray:
    """A finite (n, dim) float array ``key``, dim 2 or 3."""
    if key not in data:
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
    if a.size and np.abs(a).max() > MAX_METRES:
        raise InputError(f"a coordinate beyond the physical range (at most {MAX_METRES:g} m)", source=src, field=key)
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
    orientation : ndarray, shape (n,) or (n, 4), or None
        True orientations (angles in 2D, unit quaternions (w, x, y, z) in 3D), when the file holds them.
    seed : int or None
        Seed the ensemble was generated from, when the file records one (``-1`` in the file: none).
    """

    position: np.ndarray
    radius: float
    pairs: np.ndarray | None
    orientation: np.ndarray | None = None
    seed: int | None = None


def read_ensemble_truth(path: str | os.PathLike) -> EnsembleTruth:
    """Load and validate a ``decentral.ensemble_truth/1`` file; raise :class:`InputError` on any defect."""
    src = str(path)
    require_kind(src, TRUTH_FORMAT)
    data = read_npz_arrays(src)
    _format(data, TRUTH_FORMAT, src)
    position = _points(data, "position", src)
    radius = _number(data, "radius", src)
    if not MIN_RADIUS <= radius <= MAX_RADIUS:
        raise InputError(f"must be in [{MIN_RADIUS:g}, {MAX_RADIUS:g}] (metres), got {radius!r}", source=src,
                         field="radius")
    pairs = None
    if "pairs" in data:
        pairs = data["pairs"]
        n = position.shape[0]
        if pairs.dtype.kind not in "iu" or pairs.ndim != 2 or pairs.shape[1] != 2:
            raise InputError(f"expected a (P, 2) integer array, got {pairs.dtype} {pairs.shape}",
                             source=src, field="pairs")
        if pairs.size and (pairs.min() < 0 or pairs.max() >= n or np.any(pairs[:, 0] == pairs[:, 1])):
            raise InputError(f"ids must be distinct and in 0..{n - 1}", source=src, field="pairs")
        pairs = pairs.astype(np.int64)
    orientation = None
    if "orientation" in data:
        orientation = np.asarray(data["orientation"])
        n, dim = position.shape
        want = (n,) if dim == 2 else (n, 4)
        if orientation.dtype.kind not in "iuf" or orientation.shape != want:
            raise InputError(f"expected a {want} array, got {orientation.dtype} {orientation.shape}", source=src,
                             field="orientation")
        orientation = orientation.astype(float)
        if not np.all(np.isfinite(orientation)):
            raise InputError("non-finite value", source=src, field="orientation")
    seed = None
    if "seed" in data and np.asarray(data["seed"]).shape == () and np.asarray(data["seed"]).dtype.kind in "iu":
        seed = int(data["seed"]) if int(data["seed"]) >= 0 else None
    return EnsembleTruth(position, float(radius), pairs, orientation, seed)


def read_ensemble_positions(path: str | os.PathLike, n: int, dim: int) -> np.ndarray:
    """The ``position`` (n, dim) of an ensemble estimate ``.npz`` (its ``format``, if any, checked)."""
    src = str(path)
    require_kind(src, ESTIMATE_FORMAT)
    data = read_npz_arrays(src)
    _format(data, ESTIMATE_FORMAT, src, required=False)
    return _points(data, "position", src, n, dim)


def read_ensemble(path: str | os.PathLike, limits: Limits | None = None) -> EnsembleProblem:
    """Load and validate a ``decentral.ensemble/1`` file; raise :class:`InputError` on any defect.

    The module count ``n`` is checked against ``limits.max_modules`` before anything of size ``n``
    is allocated, and every array against the limits of :func:`read_npz_arrays`.
    """
    limits = limits or current_limits()
    src = str(path)
    require_kind(src, OBSERVATION_FORMAT)
    data = read_npz_arrays(path, limits)
    _format(data, OBSERVATION_FORMAT, src)
    dim = _int_scalar(data, "dim", src)
    n = _int_scalar(data, "n", src)
    if n > limits.max_modules:
        raise over_limit("module count", n, "max_modules", limits.max_modules, source=src, field="n")
    radius_v = _number(data, "radius", src)
    i = _int_array(data, "i", src)
    j = _int_array(data, "j", src)
    if "z" not in data:
        raise InputError("missing", source=src, field="z")
    z = data["z"]
    if z.dtype.kind not in "fiu":
        raise InputError(f"expected numbers, got dtype {z.dtype}", source=src, field="z")
    return EnsembleProblem.create(dim, n, float(radius_v), i, j, z.astype(float), source=src)


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
            raise SolverError(f"the estimate's {k!r} holds non-finite values; nothing was written to {path}")
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    write_atomic(path, lambda fh: fh.write(buf.getvalue()), binary=True)
