"""Read and validate ``decentral.ensemble/1`` observations; write ensemble estimates (CONTRACT §3).

The reader never trusts the file: every array is checked for presence, type, shape and finiteness,
and the problem's invariants (ids in range, no self-observation, symmetric pairs) are checked by
:meth:`decentral.ensemble.EnsembleProblem.validate`. Any violation raises :class:`InputError`
naming the file and the field. NPZ files are loaded with ``allow_pickle=False``.
"""

from __future__ import annotations

import io
import os
import zipfile
from typing import Any

import numpy as np

from decentral.ensemble.problem import EnsembleEstimate, EnsembleProblem
from decentral.errors import InputError
from sims.io.atomic import write_atomic

__all__ = ["OBSERVATION_FORMAT", "ESTIMATE_FORMAT", "read_ensemble", "write_ensemble_estimate"]

OBSERVATION_FORMAT = "decentral.ensemble/1"
#: ``format`` field written into estimates (the contract requires ``position`` and ``orientation``)
ESTIMATE_FORMAT = "decentral.ensemble_estimate/1"


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


def read_ensemble(path: str | os.PathLike) -> EnsembleProblem:
    """Load and validate a ``decentral.ensemble/1`` file; raise :class:`InputError` on any defect."""
    src = str(path)
    try:
        with np.load(src, allow_pickle=False) as data:
            if not isinstance(data, np.lib.npyio.NpzFile):
                raise InputError("not an .npz archive", source=src)
            if "format" not in data.files:
                raise InputError("missing", source=src, field="format")
            fmt = data["format"]
            if fmt.dtype.kind not in "US" or fmt.size != 1 or str(fmt.reshape(()).item()) != OBSERVATION_FORMAT:
                shown = str(fmt.reshape(()).item()) if fmt.size == 1 else f"array of shape {fmt.shape}"
                raise InputError(f"expected {OBSERVATION_FORMAT!r}, got {shown!r}", source=src, field="format")
            dim = _int_scalar(data, "dim", src)
            n = _int_scalar(data, "n", src)
            radius_v = _scalar(data, "radius", src)
            if isinstance(radius_v, bool) or not isinstance(radius_v, (int, float, np.integer, np.floating)):
                raise InputError(f"expected a number, got {type(radius_v).__name__}", source=src, field="radius")
            i = _int_array(data, "i", src)
            j = _int_array(data, "j", src)
            if "z" not in data.files:
                raise InputError("missing", source=src, field="z")
            z = data["z"]
            if z.dtype.kind not in "fiu":
                raise InputError(f"expected numbers, got dtype {z.dtype}", source=src, field="z")
            z = z.astype(float)
    except InputError:
        raise
    except FileNotFoundError:
        raise InputError("file not found", source=src) from None
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as err:
        raise InputError(f"cannot read as .npz ({type(err).__name__}: {err})".splitlines()[0], source=src) from None
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
