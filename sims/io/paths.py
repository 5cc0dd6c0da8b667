"""Output paths: checks made before any work (not a directory, in an existing folder, not an input),
and the file name that stands for an assembly or agent name."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Iterable
from urllib.parse import quote

from decentral.errors import InputError

__all__ = ["check_output", "name_stem"]

#: longest file-name stem :func:`name_stem` returns, in bytes (file systems allow 255 per name, suffix included)
MAX_STEM_BYTES = 200


def _same(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:  # one of them does not exist (yet)
        return a.resolve() == b.resolve()


def check_output(output: str | os.PathLike, inputs: Iterable[str | os.PathLike | None] = (), field: str = "-o") -> None:
    """Refuse an output path that is a directory, lies in a missing folder, or names one of ``inputs``.

    Raises
    ------
    InputError
        Naming the output path and the option ``field``.
    """
    out = Path(output)
    if out.is_dir():
        raise InputError("is a directory; name the file to write", source=str(output), field=field)
    if not out.resolve().parent.is_dir():
        raise InputError("output folder does not exist", source=str(output), field=field)
    for given in inputs:
        if given is not None and _same(out, Path(given)):
            raise InputError(f"is also an input ({given}); writing it would destroy that input", source=str(output),
                             field=field)


def name_stem(name: str, field: str | None = None) -> str:
    """The file-name stem that stands for ``name`` (an assembly or agent name) in a folder of per-name files.

    ``name`` is percent-encoded where it is not a letter, digit, ``_``, ``-``, ``.`` or ``~``, and a
    leading ``.`` is encoded too (``robot 1`` -> ``robot%201``, ``r/1`` -> ``r%2F1``, ``..`` -> ``%2E.``), so
    every name gives one plain, visible file name and two names never share one (``urllib.parse.unquote``
    gives the name back).

    Raises
    ------
    InputError
        Naming ``field`` when ``name`` is empty or its stem is longer than :data:`MAX_STEM_BYTES` bytes.
    """
    stem = quote(name, safe="")
    if stem.startswith("."):
        stem = "%2E" + stem[1:]
    if not stem:
        raise InputError("an empty name cannot name a file", field=field)
    if len(stem.encode()) > MAX_STEM_BYTES:
        raise InputError(f"name {name[:40]!r}... is too long for a file name ({len(stem.encode())} bytes "
                         f"percent-encoded, at most {MAX_STEM_BYTES})", field=field)
    return stem
