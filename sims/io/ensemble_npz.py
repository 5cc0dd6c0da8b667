"""Read and validate ``decentral.ensemble/1`` observations; write ensemble estimates (CONTRACT §3).

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
from typing import Any

import numpy as np

from decentral.ensemble.problem import EnsembleEstimate, EnsembleProblem
from decentral.errors import InputError, SolverError
from sims.io.atomic import write_atomic
from sims.io.limits import Limits, current_limits, over_limit

__all__ = ["OBSERVATION_FORMAT", "ESTIMATE_FORMAT", "read_npz_arrays", "read_ensemble", "write_ensemble_estimate"]

OBSERVATION_FORMAT = "decentral.ensemble/1"
#: ``format`` field written into estimates (the contract requires ``position`` and ``orientation``)
ESTIMATE_FORMAT = "decentral.ensemble_estimate/1"


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


def read_ensemble(path: str | os.PathLike, limits: Limits | None = None) -> EnsembleProblem:
    """Load and validate a ``decentral.ensemble/1`` file; raise :class:`InputError` on any defect.

    The module count ``n`` is checked against ``limits.max_modules`` before anything of size ``n``
    is allocated, and every array against the limits of :func:`read_npz_arrays`.
    """
    limits = limits or current_limits()
    src = str(path)
    data = read_npz_arrays(path, limits)
    if "format" not in data:
        raise InputError("missing", source=src, field="format")
    fmt = data["format"]
    if fmt.dtype.kind not in "US" or fmt.size != 1 or str(fmt.reshape(()).item()) != OBSERVATION_FORMAT:
        shown = str(fmt.reshape(()).item()) if fmt.size == 1 else f"array of shape {fmt.shape}"
        raise InputError(f"expected {OBSERVATION_FORMAT!r}, got {shown!r}", source=src, field="format")
    dim = _int_scalar(data, "dim", src)
    n = _int_scalar(data, "n", src)
    if n > limits.max_modules:
        raise over_limit("module count", n, "max_modules", limits.max_modules, source=src, field="n")
    radius_v = _scalar(data, "radius", src)
    if isinstance(radius_v, bool) or not isinstance(radius_v, (int, float)):
        raise InputError(f"expected a number, got {type(radius_v).__name__}", source=src, field="radius")
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
