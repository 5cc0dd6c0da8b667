"""What the report says in words and tables: values that do not vary, and the table of medians.

A quantity the same in every run (coverage 1, converged 1, a [fixed] key) is stated once, not
plotted or repeated in every row of a table; one that varies by less than :data:`STEADY_RTOL` of
its size across every run (peak memory 67.77-68.04 MB) is stated once with its range. A column of a
table whose every cell reads the same is taken out of the table and said once beside it.
"""

from __future__ import annotations

import itertools
import json
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

__all__ = ["STEADY_RTOL", "Steady", "is_number", "sort_key", "order", "steady", "collapse_constant_columns",
           "fmt", "medians_per_setting"]

#: a metric whose range across all runs is at most this fraction of its magnitude is stated, not plotted
STEADY_RTOL = 5e-3


def is_number(v: Any) -> bool:
    """A finite int or float (not a bool)."""
    return isinstance(v, (int, float)) and not isinstance(v, bool) and bool(np.isfinite(v))


def sort_key(v: Any) -> tuple:
    """Numbers first, in numeric order, then everything else by its text."""
    return (0, v, "") if is_number(v) else (1, 0, str(v))


def order(values) -> list[Any]:
    """The distinct ``values`` (scalars or tuples of them) in a reader's order."""
    values = set(values)
    if all(isinstance(v, tuple) for v in values):
        return sorted(values, key=lambda t: [sort_key(v) for v in t])
    return sorted(values, key=sort_key)


def fmt(v: Any) -> str:
    """A cell as a reader wants it: 4 significant digits, thousands separators, ``—`` for NULL."""
    if v is None:
        return "—"
    if isinstance(v, bool):
        return str(v).lower()
    if isinstance(v, float):
        if v.is_integer() and abs(v) < 1e15:
            return f"{int(v):,}"
        if abs(v) >= 1e4:
            return f"{v:,.0f}"
        return f"{v:.4g}" if abs(v) >= 1e-3 else f"{v:.3g}"
    if isinstance(v, int):
        return f"{v:,}"
    return str(v)


@dataclass(frozen=True)
class Steady:
    """A quantity stated once: its value, or its median and range when it varies a little.

    Attributes
    ----------
    name : str
    value : Any
        The value in every run (``None``: NULL in every run), or the median.
    low, high : float or None
        The range across runs when it is not exactly constant.
    """

    name: str
    value: Any
    low: float | None = None
    high: float | None = None

    @property
    def exact(self) -> bool:
        return self.low is None

    def describe(self) -> str:
        """The value as text: ``1``, ``— (not applicable)``, or ``67.9 (67.77-68.04, ±0.2 %)``."""
        if self.value is None:
            return "— (not applicable: NULL in every run)"
        if self.exact:
            return fmt(self.value)
        if fmt(self.low) == fmt(self.high):
            return f"{fmt(self.value)} (to 4 significant digits in every run)"
        half = 100 * (self.high - self.low) / 2 / max(abs(self.low), abs(self.high))
        return f"{fmt(self.value)} ({fmt(self.low)} to {fmt(self.high)}, ±{half:.2g} %)"


def steady(name: str, values: Sequence[Any], rtol: float = STEADY_RTOL) -> Steady | None:
    """``values`` as one :class:`Steady` when they do not vary (beyond ``rtol`` of their size), else ``None``.

    Exactly equal values (NULL included) are constant; numbers whose range is at most ``rtol``
    times their largest magnitude are steady, stated by their median and range; anything else
    (a mix of NULL and numbers, two different texts, a wider range) varies.
    """
    texts = {json.dumps(v) for v in values}
    if len(texts) <= 1:
        return Steady(name, values[0] if values else None)
    if not all(is_number(v) for v in values):
        return None
    lo, hi = float(min(values)), float(max(values))
    if hi - lo <= rtol * max(abs(lo), abs(hi)):
        return Steady(name, float(np.median(np.asarray(values, float))), lo, hi)
    return None


def collapse_constant_columns(head: Sequence[str], rows: Sequence[Sequence[Any]], keep: int = 0
                              ) -> tuple[list[str], list[list[Any]], list[tuple[str, Any]]]:
    """Take out of a table every column whose cells all read the same (as :func:`fmt` shows them).

    Parameters
    ----------
    head : sequence of str
        Column names.
    rows : sequence of rows
        Cells, one per column.
    keep : int
        The first ``keep`` columns stay even when constant.

    Returns
    -------
    head, rows, constants
        The table without those columns, and ``(name, value)`` of each one taken out, in order.
        A table of one row keeps every column (nothing repeats).
    """
    if len(rows) < 2:
        return list(head), [list(r) for r in rows], []
    same = [i >= keep and len({fmt(r[i]) for r in rows}) == 1 for i in range(len(head))]
    constants = [(head[i], rows[0][i]) for i in range(len(head)) if same[i]]
    kept = [i for i in range(len(head)) if not same[i]]
    return [head[i] for i in kept], [[r[i] for i in kept] for r in rows], constants


def medians_per_setting(keys: Sequence[str], metrics: Sequence[str], ok: Sequence[dict]
                        ) -> tuple[list[str], list[list[Any]]]:
    """The median of every metric per combination of ``keys``, with the number of runs.

    Returns ``(head, rows)``: ``[*keys, "runs", *metrics]`` and one row per combination, in a
    reader's order; a metric with no number among a combination's runs is ``None`` there.
    """
    out = []
    for combo, rs in itertools.groupby(sorted(ok, key=lambda r: [sort_key(r[k]) for k in keys]),
                                       key=lambda r: tuple(r[k] for k in keys)):
        rs = list(rs)
        meds = []
        for m in metrics:
            ys = [r[m] for r in rs if is_number(r.get(m))]
            meds.append(float(np.median(ys)) if ys else None)
        out.append([*combo, len(rs), *meds])
    return [*keys, "runs", *metrics], out
