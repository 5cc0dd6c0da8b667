"""The report's figures: one metric against one swept parameter, drawn so that noise looks like noise.

Each figure shows the median over the replicates (line), their interquartile range (band, or error
bars between categories) and every run (dots), one colour per combination of the other swept
parameters. A linear y axis starts at zero (:func:`y_limits`): a 0.4 % change is drawn as the
small change it is. Sizes spanning 8x or more get logarithmic axes, and time against size a
log-log plot with its power-law fit. Legends sit below the axes, never over the data.
"""

from __future__ import annotations

import io
from typing import Callable, Sequence

import numpy as np

from sims.lab.study.fits import Fit, fit_log, fit_power
from sims.lab.study.summary import is_number, order

__all__ = ["SIZES", "FIT_BOTH", "FIT_POWER", "y_limits", "draw_metric", "plot_metric"]

#: size parameters: the x of the fits
SIZES = ("n", "n_assemblies")
#: metrics fitted against size with both laws (messages), and with the power law only (time)
FIT_BOTH = ("messages_per_module", "messages")
FIT_POWER = ("seconds", "cpu_seconds", "solve_cpu_seconds")
#: headroom above the largest value drawn
_HEADROOM = 1.08


def y_limits(values: Sequence[float], log: bool = False) -> tuple[float, float] | None:
    """The y range of a figure holding ``values`` (medians, band edges and runs).

    On a linear axis it includes zero: ``(0, top)`` when every value is >= 0, ``(bottom, 0)`` when
    every value is <= 0; values on both sides of zero already include it (``None``: automatic). A
    logarithmic axis is left automatic.
    """
    values = [float(v) for v in values if is_number(v)]
    if log or not values:
        return None
    lo, hi = min(values), max(values)
    if lo >= 0:
        return (0.0, hi * _HEADROOM if hi > 0 else 1.0)
    if hi <= 0:
        return (lo * _HEADROOM, 0.0)
    return None


def _quartiles(ys: np.ndarray) -> tuple[float, float, float]:
    q1, q2, q3 = np.percentile(ys, [25, 50, 75])
    return float(q1), float(q2), float(q3)


def plot_metric(metric: str, x: str, others: Sequence[str], rows: Sequence[dict], label: Callable[[str], str],
                size_col: str | None = None) -> tuple[bytes, list[tuple[str, Fit]]]:
    """:func:`draw_metric` as PNG bytes (110 dpi, trimmed to what is drawn), and its fits."""
    import matplotlib.pyplot as plt

    fig, fits = draw_metric(metric, x, others, rows, label, size_col)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue(), fits


def draw_metric(metric: str, x: str, others: Sequence[str], rows: Sequence[dict], label: Callable[[str], str],
                size_col: str | None = None):
    """One figure of ``metric`` against ``x``: median, interquartile range and runs per group.

    Parameters
    ----------
    metric, x : str
        Columns of ``rows``: the y and the x.
    others : sequence of str
        The other swept parameters: one series per combination of their values.
    rows : sequence of dict
        The 'ok' rows.
    label : callable
        Column -> axis label with units.
    size_col : str, optional
        Column holding the size actually made (``n_modules``), used as N by the fits.

    Returns
    -------
    fig : matplotlib.figure.Figure
        One axes; the caller closes it.
    fits : list of (series label, Fit)
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    xs = order(r[x] for r in rows)
    numeric = all(is_number(v) for v in xs)
    pos = {v: (float(v) if numeric else float(i)) for i, v in enumerate(xs)}
    groups = order(tuple(r[o] for o in others) for r in rows) if others else [()]
    fig, ax = plt.subplots(figsize=(4.6, 3.1))
    fits: list[tuple[str, Fit]] = []
    drawn: list[float] = []
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    log_y = (numeric and x in SIZES and metric in FIT_POWER
             and all(is_number(r.get(metric)) and r[metric] > 0 for r in rows))
    for gi, group in enumerate(groups):
        color = colors[gi % len(colors)]
        mine = [r for r in rows if tuple(r[o] for o in others) == group and is_number(r.get(metric))]
        if not mine:
            continue
        shift = 0.0 if numeric else 0.12 * (gi - (len(groups) - 1) / 2)
        at, med, lo, hi = [], [], [], []
        for v in xs:
            ys = np.array([r[metric] for r in mine if r[x] == v], float)
            if ys.size:
                q1, q2, q3 = _quartiles(ys)
                at.append(pos[v] + shift), med.append(q2), lo.append(q1), hi.append(q3)
                ax.plot(np.full(ys.size, pos[v] + shift), ys, ".", color=color, alpha=0.35, markersize=4,
                        zorder=1)
                drawn.extend(ys.tolist())
        name = ", ".join(f"{label(k)} = {v}" for k, v in zip(others, group)) if others else "median"
        if numeric:
            ax.plot(at, med, "o-", color=color, label=name, markersize=4, zorder=3)
            if any(h > l for h, l in zip(hi, lo)):
                ax.fill_between(at, lo, hi, color=color, alpha=0.18, linewidth=0, zorder=2)
        else:  # categories: no line between them; the interquartile range as an error bar
            ax.errorbar(at, med, yerr=[np.subtract(med, lo), np.subtract(hi, med)], fmt="o", color=color,
                        capsize=3, label=name, markersize=4, zorder=3)
        if numeric and x in SIZES and (metric in FIT_BOTH or metric in FIT_POWER) and min(at) > 0:
            n = [r[size_col] if size_col and is_number(r.get(size_col)) else r[x] for r in mine]
            y = [r[metric] for r in mine]
            grid = np.geomspace(min(at), max(at), 60)
            for kind, style in zip((fit_log, fit_power) if metric in FIT_BOTH else (fit_power,), ("--", ":")):
                f = kind(n, y)
                if f is None:
                    continue
                fits.append((name, f))
                ax.plot(grid, f(grid), style, color=color, linewidth=1,
                        label=f"{f.formula(_short(metric))} (R² {f.r2:.3f})")
    ax.set_xlabel(label(x))
    ax.set_ylabel(label(metric))
    if not log_y:
        ax.ticklabel_format(axis="y", useOffset=False, style="plain")
    if numeric:
        if min(xs) > 0 and max(xs) / min(xs) >= 8:
            ax.set_xscale("log")
            _plain_ticks(ax.xaxis, at=[float(v) for v in xs])
        if log_y:
            ax.set_yscale("log")
            _plain_ticks(ax.yaxis)
    else:
        ax.set_xticks(range(len(xs)), [str(v) for v in xs])
        ax.set_xlim(-0.5, len(xs) - 0.5)
    limits = y_limits(drawn, log=log_y)
    if limits:
        ax.set_ylim(*limits)
    if not log_y and max(abs(v) for v in drawn or [0]) >= 1e4:
        from matplotlib.ticker import FuncFormatter

        ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:,.0f}"))
    ax.grid(True, alpha=0.3)
    for side in ("top", "right"):
        ax.spines[side].set_visible(False)
    handles, labels = ax.get_legend_handles_labels()
    if len(labels) > 1:  # below the axes, outside the data
        ax.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, -0.22), ncol=1 if len(labels) > 4 else 2,
                  fontsize=7.5, frameon=False)
    return fig, fits


def _plain_ticks(axis, at: list[float] | None = None) -> None:
    """Plain numbers (1,000; 0.5; 20) on a logarithmic ``axis``, at ``at`` or at 1-2-5 steps."""
    from matplotlib.ticker import FixedLocator, FuncFormatter, LogLocator, NullFormatter

    axis.set_major_locator(FixedLocator(at) if at else LogLocator(subs=(1.0, 2.0, 5.0)))
    axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:,.0f}" if v >= 100 else f"{v:g}"))
    axis.set_minor_formatter(NullFormatter())


def _short(metric: str) -> str:
    short = {"messages_per_module": "messages/module", "seconds": "t", "cpu_seconds": "t", "solve_cpu_seconds": "t"}
    return short.get(metric, metric)
