"""Reading a text input file, with every way it can fail turned into one :class:`InputError` naming it."""

from __future__ import annotations

import os

from decentral.errors import InputError

__all__ = ["read_text"]


def read_text(path: str | os.PathLike) -> str:
    """The UTF-8 text of ``path``; a missing, unreadable or non-UTF-8 file is an :class:`InputError`."""
    try:
        with open(path, encoding="utf-8") as fh:
            return fh.read()
    except FileNotFoundError:
        raise InputError("file not found", source=str(path)) from None
    except IsADirectoryError:
        raise InputError("is a directory, not a file", source=str(path)) from None
    except UnicodeDecodeError:
        raise InputError("not a UTF-8 text file", source=str(path)) from None
    except OSError as err:
        raise InputError(f"cannot read file ({err.strerror})", source=str(path)) from None
