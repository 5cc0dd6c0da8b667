"""Typed options of a study cell: one declaration per key, one checker for all of them.

Every key a cell command accepts is an :class:`Option` (its default and what values it takes). A
value read from TOML is checked and normalized once, before any cell runs (an integer given for a
float option becomes a float, so ``loss = 0`` and ``loss = 0.0`` name the same cell).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable

from decentral.errors import InputError

__all__ = ["Option", "check_value", "require"]


@dataclass(frozen=True)
class Option:
    """One key of a cell command.

    Attributes
    ----------
    default : Any
        Value when the study does not give the key (``None``: the command's own default).
    kind : type
        ``bool``, ``int``, ``float`` or ``str``.
    choices : tuple, optional
        Allowed values (strings).
    valid : callable, optional
        ``valid(value) -> str | None``: a reason the value is refused, or ``None``.
    help : str
        One line for the documentation.
    """

    default: Any
    kind: type
    choices: tuple = ()
    valid: Callable[[Any], str | None] | None = None
    help: str = ""


def check_value(key: str, value: Any, option: Option) -> Any:
    """Return ``value`` normalized to ``option.kind``; raise :class:`InputError` naming ``key``."""
    kind = option.kind
    if kind is bool:
        ok = isinstance(value, bool)
    elif kind is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif kind is float:
        ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
        value = float(value) if ok else value
    else:
        ok = isinstance(value, str)
    if not ok:
        raise InputError(f"expected a {kind.__name__}, got {value!r}", field=key)
    if option.choices and value not in option.choices:
        raise InputError(f"must be one of {', '.join(map(str, option.choices))}, got {value!r}", field=key)
    reason = option.valid(value) if option.valid else None
    if reason:
        raise InputError(f"{reason}, got {value!r}", field=key)
    return value


def require(test: Callable[[Any], bool], reason: str) -> Callable[[Any], str | None]:
    """A ``valid`` callable refusing values for which ``test`` is false with ``reason``."""
    return lambda value: None if test(value) else reason
