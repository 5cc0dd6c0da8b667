"""Reading a text input file, with every way it can fail turned into one :class:`InputError` naming it.

The file's size is checked against ``DECENTRAL_MAX_FILE_MB`` (:mod:`sims.io.limits`) before it is
read, and no more than that is ever read.
"""

from __future__ import annotations

import os

from decentral.errors import InputError
from sims.io.limits import Limits, current_limits, over_limit

__all__ = ["read_text"]


def read_text(path: str | os.PathLike, limits: Limits | None = None) -> str:
    """The UTF-8 text of ``path``; a missing, unreadable, oversized or non-UTF-8 file is an :class:`InputError`."""
    limits = limits or current_limits()
    src = str(path)
    cap = int(limits.max_file_mb * 1e6)
    try:
        with open(path, "rb") as fh:
            size = os.fstat(fh.fileno()).st_size
            raw = fh.read(cap + 1) if size <= cap else b""  # bounded even if the file grows meanwhile
    except FileNotFoundError:
        raise InputError("file not found", source=src) from None
    except IsADirectoryError:
        raise InputError("is a directory, not a file", source=src) from None
    except OSError as err:
        raise InputError(f"cannot read file ({err.strerror})", source=src) from None
    if size > cap or len(raw) > cap:
        raise over_limit("file size", round(max(size, len(raw)) / 1e6, 1), "max_file_mb", limits.max_file_mb, " MB",
                         source=src)
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        raise InputError("not a UTF-8 text file", source=src) from None
