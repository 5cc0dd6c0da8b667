"""Strict, bounded JSON reading shared by every reader of the contract's JSON files.

Before :func:`json.loads` runs, the file's size and its nesting depth are checked against
:mod:`sims.io.limits` (a vectorized pre-scan of the brackets outside strings, so a file of 100,000
nested brackets is refused without recursing); while it runs, integer literals longer than the
digit limit and keys given twice in one object are refused (a node id listed twice must not be
silently the last one). ``NaN`` and ``Infinity`` still parse, so that the validators can name
the field that holds them.
"""

from __future__ import annotations

import json
import os
from typing import Any

import numpy as np

from decentral.errors import InputError
from sims.io.limits import Limits, current_limits, over_limit
from sims.io.text import read_text

__all__ = ["load_json", "loads_json", "json_depth"]

def json_depth(text: str) -> int:
    """Deepest nesting of arrays/objects in ``text`` (brackets inside strings do not count).

    Vectorized over the UTF-8 bytes: a quote opens or closes a string unless an odd run of
    backslashes precedes it; brackets between an odd and an even quote are inside a string.
    """
    raw = np.frombuffer(text.encode("utf-8"), dtype=np.uint8)
    quotes = np.flatnonzero(raw == ord('"'))
    if quotes.size and "\\" in text:
        slash = raw == ord("\\")
        starts = np.flatnonzero(slash & ~np.concatenate(([False], slash[:-1])))  # first byte of each run
        escaped = (quotes > 0) & slash[np.maximum(quotes - 1, 0)]
        q = quotes[escaped]
        run = q - starts[np.searchsorted(starts, q - 1, side="right") - 1]  # backslashes right before q
        escaped[escaped] = run % 2 == 1
        quotes = quotes[~escaped]
    brackets = np.flatnonzero((raw == ord("[")) | (raw == ord("]")) | (raw == ord("{")) | (raw == ord("}")))
    brackets = brackets[np.searchsorted(quotes, brackets) % 2 == 0]
    if not brackets.size:
        return 0
    opening = (raw[brackets] == ord("[")) | (raw[brackets] == ord("{"))
    return int(np.cumsum(np.where(opening, 1, -1).astype(np.int32)).max())


def loads_json(text: str, source: str, limits: Limits | None = None) -> Any:
    """Parse ``text`` (the contents of ``source``) under ``limits``; raise :class:`InputError` naming ``source``."""
    limits = limits or current_limits()
    depth = json_depth(text)
    if depth > limits.max_json_depth:
        raise over_limit("nesting depth", depth, "max_json_depth", limits.max_json_depth, source=source)

    def bounded_int(literal: str) -> int:
        digits = len(literal.lstrip("-"))
        if digits > limits.max_int_digits:
            raise over_limit("an integer of", digits, "max_int_digits", limits.max_int_digits, " digits",
                             source=source)
        return int(literal)

    def unique_keys(pairs: list[tuple[str, Any]]) -> dict:
        obj: dict = {}
        for key, value in pairs:
            if key in obj:
                raise InputError("key given twice in one object", source=source, field=key)
            obj[key] = value
        return obj

    try:
        return json.loads(text, object_pairs_hook=unique_keys, parse_int=bounded_int)
    except json.JSONDecodeError as err:
        raise InputError(f"not valid JSON ({err.msg} at line {err.lineno})", source=source) from None
    except RecursionError:  # only below the depth pre-scan's limit when that is raised very high
        raise InputError("JSON nested too deeply to parse", source=source) from None


def load_json(path: str | os.PathLike, limits: Limits | None = None) -> Any:
    """Read (:func:`sims.io.text.read_text`) and parse the JSON file ``path`` under ``limits``; any
    defect is an :class:`InputError` naming it."""
    limits = limits or current_limits()
    return loads_json(read_text(path, limits), str(path), limits)
