"""Checks on output paths, made before any work: not a directory, in an existing folder, not an input."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Iterable

from decentral.errors import InputError

__all__ = ["check_output"]


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
