"""A study specification: the TOML file that declares a sweep (docs/formats.md).

.. code-block:: toml

    name = "loss-sweep"
    command = "localize"            # localize | ensemble
    [fixed]
    scenario = "multi"
    n_assemblies = 5
    [grid]
    loss = [0.0, 0.3]
    seed = [1, 2, 3]

A study is the product of the lists in ``[grid]`` (in the order the keys are written, the last key
varying fastest), each cell also given the values of ``[fixed]``. Values are TOML scalars (strings,
integers, floats, booleans). This module only reads and shapes the file; which keys a command
accepts is checked by :func:`sims.lab.study.cells.check_cells`.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import re
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Union

from decentral.errors import InputError
from sims.io.kinds import require_kind
from sims.io.validate import unknown_name

__all__ = ["Value", "StudySpec", "read_spec", "parse_spec", "cell_key", "cell_hash"]

#: a parameter value: what one SQLite column holds
Value = Union[str, int, float, bool]

COMMANDS = ("localize", "ensemble")
TOP_KEYS = ("name", "command", "description", "fixed", "grid")
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


@dataclass(frozen=True)
class StudySpec:
    """A parsed study file.

    Attributes
    ----------
    name : str
        The study's name (titles of the report).
    command : str
        ``"localize"`` or ``"ensemble"``: what each cell runs.
    fixed : Mapping[str, Value]
        Values every cell gets.
    grid : Mapping[str, tuple of Value]
        Swept values; the cells are their product.
    text : str
        The file's text, kept for provenance.
    source : str
        Where the spec was read from (error messages).
    description : str
        Free text (shown in the report).
    """

    name: str
    command: str
    fixed: Mapping[str, Value]
    grid: Mapping[str, tuple]
    text: str = ""
    source: str = "<spec>"
    description: str = ""

    @property
    def keys(self) -> tuple[str, ...]:
        """Every parameter key: ``[fixed]`` keys, then ``[grid]`` keys, in the file's order."""
        return tuple(self.fixed) + tuple(self.grid)

    @property
    def cell_count(self) -> int:
        """How many cells the grid makes (the product of its list lengths; 1 without a grid)."""
        return math.prod(len(v) for v in self.grid.values())

    def cells(self) -> list[dict[str, Value]]:
        """The parameters of every cell, in grid order (first key slowest).

        Raises
        ------
        InputError
            If :attr:`cell_count` is over ``DECENTRAL_MAX_CELLS`` (checked before any cell exists).
        """
        from sims.io.limits import current_limits, over_limit

        limit = current_limits().max_cells
        if self.cell_count > limit:
            raise over_limit("cell count", self.cell_count, "max_cells", limit, source=self.source, field="[grid]")
        names = list(self.grid)
        return [{**self.fixed, **dict(zip(names, combo))}
                for combo in itertools.product(*(self.grid[k] for k in names))]

    def section_of(self, key: str) -> str:
        """``"[fixed]"`` or ``"[grid]"``: where ``key`` is written (for messages)."""
        return "[grid]" if key in self.grid else "[fixed]"


def _scalar(value, source: str, field: str) -> Value:
    if isinstance(value, bool) or isinstance(value, (str, int)):
        return value
    if isinstance(value, float):
        if not math.isfinite(value):
            raise InputError(f"must be finite, got {value!r}", source=source, field=field)
        return value
    raise InputError(f"must be a string, number or boolean, got {type(value).__name__}", source=source, field=field)


def _key(key: str, source: str, section: str) -> str:
    if not _NAME.match(key):
        hint = f" (write {key.replace('-', '_')})" if _NAME.match(key.replace("-", "_")) else ""
        raise InputError(f"a key must be a name made of letters, digits and underscores{hint}",
                         source=source, field=f"{section} {key}")
    return key


def parse_spec(text: str, source: str = "<spec>") -> StudySpec:
    """Parse the TOML ``text`` of a study; raises :class:`InputError` naming ``source`` and the key."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise InputError(f"not valid TOML: {err}", source=source) from None
    for key in data:
        if key not in TOP_KEYS:
            raise unknown_name(key, TOP_KEYS, "unknown key at the top of a study").located(source)
    name = data.get("name")
    if not isinstance(name, str) or not name.strip():
        raise InputError("missing or empty (a study needs a name)", source=source, field="name")
    command = data.get("command")
    if command not in COMMANDS:
        raise InputError(f"must be one of {', '.join(COMMANDS)}, got {command!r}", source=source, field="command")
    description = data.get("description", "")
    if not isinstance(description, str):
        raise InputError("must be a string", source=source, field="description")
    fixed_raw, grid_raw = data.get("fixed", {}), data.get("grid", {})
    for section, table in (("fixed", fixed_raw), ("grid", grid_raw)):
        if not isinstance(table, dict):
            raise InputError("must be a table", source=source, field=f"[{section}]")
    fixed = {_key(k, source, "[fixed]"): _scalar(v, source, f"[fixed] {k}") for k, v in fixed_raw.items()}
    grid = {}
    for k, values in grid_raw.items():
        field = f"[grid] {_key(k, source, '[grid]')}"
        if k in fixed:
            raise InputError("given in both [fixed] and [grid]", source=source, field=field)
        if not isinstance(values, list) or not values:
            raise InputError("must be a non-empty list of values", source=source, field=field)
        values = tuple(_scalar(v, source, field) for v in values)
        if len({json.dumps(v) for v in values}) != len(values):
            raise InputError("lists a value twice", source=source, field=field)
        grid[k] = values
    return StudySpec(name.strip(), command, fixed, grid, text, source, description)


def read_spec(path: str | Path) -> StudySpec:
    """Read and parse the study file at ``path``."""
    require_kind(path, "study-spec")
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise InputError(f"cannot read: {err}", source=str(path)) from None
    return parse_spec(text, str(path))


def cell_key(params: Mapping[str, Value]) -> str:
    """The canonical text of a cell's parameters (sorted JSON): the cell's identity in the store."""
    return json.dumps(dict(params), sort_keys=True, separators=(",", ":"))


def cell_hash(params: Mapping[str, Value]) -> str:
    """A short stable hash of :func:`cell_key` (16 hex digits), for names and logs."""
    return hashlib.sha256(cell_key(params).encode()).hexdigest()[:16]
