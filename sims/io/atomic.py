"""Atomic output: a file is either written whole or not at all.

The contract forbids half-written outputs, so every writer goes through :func:`write_atomic`,
which writes to a temporary file beside the target and renames it over the target only on success.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any, Callable

from decentral.errors import InputError

__all__ = ["write_atomic", "write_json_atomic"]


def write_atomic(path: str | os.PathLike, write: Callable[[Any], None], *, binary: bool = False,
                 mode: int | None = None) -> None:
    """Call ``write(fileobj)`` on a temporary file next to ``path``, then rename it to ``path``.

    The file gets permission bits ``mode`` (e.g. ``0o600`` for a secret; default: what ``open()``
    would give). Raises :class:`InputError` naming ``path`` if its folder does not exist or is not
    writable. On any error the temporary file is removed and ``path`` is left as it was.
    """
    target = Path(path)
    folder = target.parent if str(target.parent) else Path(".")
    if not folder.is_dir():
        raise InputError("output folder does not exist", source=str(target))
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".part", dir=folder)
    except OSError as err:
        raise InputError(f"cannot write output ({err.strerror})", source=str(target)) from None
    try:
        with os.fdopen(fd, "wb" if binary else "w", **({} if binary else {"encoding": "utf-8"})) as fh:
            write(fh)
        os.chmod(tmp, 0o666 & ~_umask() if mode is None else mode)  # mkstemp makes 0600
        os.replace(tmp, target)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_json_atomic(path: str | os.PathLike, payload: Any, *, mode: int | None = None) -> None:
    """Write ``payload`` as indented JSON to ``path`` atomically (NaN/inf are refused), with permission bits ``mode``."""
    text = json.dumps(payload, indent=1, allow_nan=False)
    write_atomic(path, lambda fh: fh.write(text + "\n"), mode=mode)
