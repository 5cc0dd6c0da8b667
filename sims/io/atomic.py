"""Atomic output: a file is either written whole or not at all, and no temporary file outlives its run.

The contract forbids half-written outputs, so every writer goes through :func:`write_atomic`: the
data is prepared first, then written to a temporary file beside the target, named
``.TARGET.PID.XXXXXXXX.part``, and renamed over the target only on success. Any exception (and
SIGINT/SIGTERM, which the CLI turns into one) removes the temporary file. ``kill -9`` cannot run
any handler, so the pid in the name lets the next write to the same target recognise temporary
files whose process is gone and remove them.
"""

from __future__ import annotations

import json
import math
import os
import re
import tempfile
from pathlib import Path
from typing import Any, Callable

from decentral.errors import InputError

__all__ = ["write_atomic", "write_json_atomic", "remove_stale_parts", "first_non_finite"]


def write_atomic(path: str | os.PathLike, write: Callable[[Any], None], *, binary: bool = False,
                 mode: int | None = None) -> None:
    """Call ``write(fileobj)`` on a temporary file next to ``path``, then rename it to ``path``.

    The file gets permission bits ``mode`` (e.g. ``0o600`` for a secret; default: what ``open()``
    would give). Raises :class:`InputError` naming ``path`` if it is a directory or its folder does
    not exist or is not writable. On any error the temporary file is removed and ``path`` is left
    as it was.
    """
    target = Path(path)
    folder = target.parent if str(target.parent) else Path(".")
    if target.is_dir():
        raise InputError("is a directory; name the file to write", source=str(target))
    if not folder.is_dir():
        raise InputError("output folder does not exist", source=str(target))
    remove_stale_parts(target)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.{os.getpid()}.", suffix=".part", dir=folder)
    except OSError as err:
        raise InputError(f"cannot write output ({err.strerror})", source=str(target)) from None
    try:
        with os.fdopen(fd, "wb" if binary else "w", **({} if binary else {"encoding": "utf-8"})) as fh:
            write(fh)
        os.chmod(tmp, 0o666 & ~_umask() if mode is None else mode)  # mkstemp makes 0600
        os.replace(tmp, target)
    except OSError as err:
        _unlink(tmp)
        raise InputError(f"cannot write output ({err.strerror})", source=str(target)) from None
    except BaseException:
        _unlink(tmp)
        raise


def remove_stale_parts(target: str | os.PathLike) -> list[Path]:
    """Remove the temporary files of ``target`` left by processes that no longer exist; return them."""
    target = Path(target)
    folder = target.parent if str(target.parent) else Path(".")
    pattern = re.compile(rf"\.{re.escape(target.name)}\.(\d+)\.[^.]+\.part")
    removed = []
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return removed
    for entry in entries:
        m = pattern.fullmatch(entry.name)
        if m and not _alive(int(m.group(1))):
            _unlink(entry.path)
            removed.append(Path(entry.path))
    return removed


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, ValueError):
        return True  # another user's process (or not a pid): leave its file alone
    return True


def _unlink(path: str | os.PathLike) -> None:
    try:
        os.unlink(path)
    except FileNotFoundError:
        pass


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def first_non_finite(value: Any, where: str = "") -> str | None:
    """The path (``steps[2].poses.A1.p[0]``) of the first NaN or infinite float in a JSON-ready value, or None."""
    if isinstance(value, float):
        return None if math.isfinite(value) else (where or "(top level)")
    if isinstance(value, dict):
        items = ((f"{where}.{k}" if where else str(k), v) for k, v in value.items())
    elif isinstance(value, (list, tuple)):
        items = ((f"{where}[{k}]", v) for k, v in enumerate(value))
    else:
        return None
    for path, item in items:
        found = first_non_finite(item, path)
        if found is not None:
            return found
    return None


def write_json_atomic(path: str | os.PathLike, payload: Any, *, mode: int | None = None) -> None:
    """Write ``payload`` as indented JSON to ``path`` atomically, with permission bits ``mode``.

    Raises
    ------
    InputError
        Naming ``path`` and the field, if ``payload`` holds a NaN or an infinity (JSON has none, and
        a non-finite number is never an answer); nothing is written then.
    """
    try:
        text = json.dumps(payload, indent=1, allow_nan=False)
    except ValueError:
        field = first_non_finite(payload)
        if field is None:
            raise
        raise InputError("is not a finite number; nothing was written", source=str(path), field=field) from None
    write_atomic(path, lambda fh: fh.write(text + "\n"), mode=mode)
