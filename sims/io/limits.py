"""The resource limits every command enforces before it allocates, and how to raise them.

Each limit has a default and an environment variable that overrides it for one run, e.g.
``DECENTRAL_MAX_MODULES=5000000 decentral ensemble big.npz -o est.npz``. Limits are checked from
what a file declares (its size on disk, the shapes in its ``.npy`` headers, the size in its image
header, the nesting of its JSON) before the data is decoded, and a file over a limit ends the
command with one line naming the file, the field and the variable that raises the limit.

========================  ======================  ====================================================
variable                  default                 what it bounds
========================  ======================  ====================================================
DECENTRAL_MAX_FILE_MB     512                     size of a text input (JSON, TOML, ...) or image on disk
DECENTRAL_MAX_JSON_DEPTH  32                      nesting of arrays and objects in a JSON input
DECENTRAL_MAX_INT_DIGITS  32                      digits of an integer literal in a JSON input
DECENTRAL_MAX_MODULES     1000000                 module count ``n`` of an ensemble
DECENTRAL_MAX_AGENTS      100000                  module count of a ``--distributed`` run (an agent each)
DECENTRAL_MAX_ASSEMBLIES  512                     assemblies of an observation log (a joint window is dense)
DECENTRAL_MAX_ARRAY_MB    1024                    decompressed bytes of all arrays of one ``.npz``
DECENTRAL_MAX_PIXELS      40000000                width x height of one image or video frame
DECENTRAL_MAX_CELLS       100000                  cells of a study (the product of its ``[grid]`` lists)
========================  ======================  ====================================================
"""

from __future__ import annotations

import os
from dataclasses import dataclass, fields

from decentral.errors import InputError

__all__ = ["Limits", "current_limits", "ENV_PREFIX", "over_limit"]

ENV_PREFIX = "DECENTRAL_"


@dataclass(frozen=True)
class Limits:
    """Resource limits of one run (see the module docstring for the variables that set them).

    Attributes
    ----------
    max_file_mb : float
        Largest text input (JSON, TOML, trajectory) or image file, megabytes (10**6 bytes) on disk
        (videos are streamed).
    max_json_depth : int
        Deepest nesting of JSON arrays/objects (a ``decentral.log/1`` needs 6).
    max_int_digits : int
        Most digits of one JSON integer literal.
    max_modules : int
        Largest ensemble module count ``n``.
    max_agents : int
        Largest module count of a distributed ensemble run, which holds one agent object per module.
    max_assemblies : int
        Most assemblies in an observation log: a joint window over m assemblies and K steps holds
        dense (2 m K)^2 matrices.
    max_array_mb : float
        Largest total of decompressed array bytes in one ``.npz``, megabytes.
    max_pixels : int
        Largest image or video frame, width x height.
    max_cells : int
        Most cells in one study: the product of the lengths of its ``[grid]`` lists, checked before
        any cell is built (each cell is a parameter row in memory and in the store).
    """

    max_file_mb: float = 512.0
    max_json_depth: int = 32
    max_int_digits: int = 32
    max_modules: int = 1_000_000
    max_agents: int = 100_000
    max_assemblies: int = 512
    max_array_mb: float = 1024.0
    max_pixels: int = 40_000_000
    max_cells: int = 100_000

    @staticmethod
    def variable(name: str) -> str:
        """The environment variable of limit ``name`` (``max_pixels`` -> ``DECENTRAL_MAX_PIXELS``)."""
        return ENV_PREFIX + name.upper()


def current_limits() -> Limits:
    """The limits in force: the defaults, each overridden by its environment variable when set.

    Raises
    ------
    InputError
        If a variable is set to something other than a positive number (an integer for the
        integer limits), naming the variable.
    """
    values = {}
    for f in fields(Limits):
        var = Limits.variable(f.name)
        raw = os.environ.get(var)
        if raw is None or not raw.strip():
            continue
        try:
            value = int(raw) if f.type in (int, "int") else float(raw)
        except ValueError:
            value = None
        if value is None or not value > 0 or value != value or value == float("inf"):
            raise InputError(f"must be a positive {'integer' if f.type in (int, 'int') else 'number'}, got {raw!r}",
                             field=var)
        values[f.name] = value
    return Limits(**values)


def over_limit(what: str, value: float, name: str, limit: float, unit: str = "", *,
               source: str | None = None, field: str | None = None) -> InputError:
    """The one-line error for ``value`` of ``what`` exceeding limit ``name``, naming the variable that raises it."""
    return InputError(f"{what} {_fmt(value)}{unit} is over the limit of {_fmt(limit)}{unit} "
                      f"(set {Limits.variable(name)} to raise it)", source=source, field=field)


def _fmt(x: float) -> str:
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e18 else f"{x:.4g}"
