"""The study report: ``DIR/report.html`` (figures embedded) and the PNG figures beside it.

Made from the store alone (``DIR/study.sqlite``; a bare ``runs`` table is enough). For every metric
and every swept parameter (a parameter with more than one value among the 'ok' rows, other than
the seeds) one figure shows the median over seeds and its interquartile band, one line per
combination of the other swept parameters. Where the swept parameter is a size (``n`` modules or
``n_assemblies``) it adds the fits users ask for: messages per module against ``a + b ln N`` and a
power law (with R²), and time against a power law (its exponent).
"""

from __future__ import annotations

import base64
import html
import io
import itertools
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from sims.io.atomic import write_atomic
from sims.study.fits import Fit, fit_log, fit_power
from sims.study.store import BOOKKEEPING, DB_NAME, read_runs

__all__ = ["Figure", "ReportResult", "write_report", "LABELS"]

#: column -> axis label with units (a reader's words, not the column's)
LABELS = {
    "pos_error_m": "position error [m]",
    "rel_error_pct": "relative position error [%]",
    "angle_error_deg": "yaw error [deg]",
    "coverage": "coverage (fraction of poses placed)",
    "messages": "messages sent (all agents)",
    "bytes": "bytes sent (all agents)",
    "rounds": "consensus rounds (all steps)",
    "converged": "all agents converged (1 = yes)",
    "certified": "windows certified optimal (fraction)",
    "steps": "steps",
    "global_rms": "global RMS error [module radii]",
    "local_rms": "local RMS error [module radii]",
    "cost": "negative log-likelihood",
    "messages_per_module": "messages per module",
    "levels": "hierarchy levels",
    "n_modules": "modules",
    "observations": "observations",
    "seconds": "time per run [s]",
    "cpu_seconds": "CPU time per run [s]",
    "solve_cpu_seconds": "localization CPU time [s]",
    "peak_mb": "peak memory [MB]",
    "n": "modules N",
    "n_assemblies": "assemblies N",
    "loss": "message loss probability",
    "window": "window K [steps]",
    "tol": "refinement tolerance [module radii]",
    "shape": "shape",
    "method": "method",
    "mode": "mode",
    "scenario": "scenario",
    "distributed": "distributed",
}
#: replicate parameters: spread across them, never an axis
SEEDS = ("seed", "scenario_seed")
#: size parameters: the x of the fits
SIZES = ("n", "n_assemblies")
#: metrics fitted against size with both laws (messages), and with the power law only (time)
FIT_BOTH = ("messages_per_module", "messages")
FIT_POWER = ("seconds", "cpu_seconds", "solve_cpu_seconds")
#: metrics that are not worth a figure of their own
NOT_PLOTTED = ("n_modules", "observations")


def _label(name: str) -> str:
    return LABELS.get(name, name.replace("_", " "))


@dataclass
class Figure:
    """One figure of the report: its file, caption and fits."""

    path: Path
    title: str
    caption: str
    png: bytes
    fits: list[tuple[str, Fit]] = field(default_factory=list)


@dataclass(frozen=True)
class ReportResult:
    """What :func:`write_report` wrote."""

    html: Path
    figures: tuple[Path, ...]
    rows: int
    failed: int


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v)


def _columns(facts: dict, runs: list[dict]) -> tuple[list[str], list[str]]:
    """(parameter columns, metric columns) of the store."""
    names = list(runs[0]) if runs else []
    if "params" in facts and "metrics" in facts:
        return json.loads(facts["params"]), json.loads(facts["metrics"]) + ["seconds", "cpu_seconds", "peak_mb"]
    known = set(LABELS) - {"n", "n_assemblies", "loss", "window", "tol", "shape", "method", "mode", "scenario",
                           "distributed", "steps_param"}
    metrics = [c for c in names if c in known or c in ("seconds", "cpu_seconds", "peak_mb")]
    params = [c for c in names if c not in BOOKKEEPING and c not in metrics]
    return params, metrics


def _sort_key(v: Any) -> tuple:
    """Numbers first, in numeric order, then everything else by its text."""
    return (0, v, "") if _is_number(v) else (1, 0, str(v))


def _order(values) -> list[Any]:
    """The distinct ``values`` (scalars or tuples of them) in a reader's order."""
    values = set(values)
    if all(isinstance(v, tuple) for v in values):
        return sorted(values, key=lambda t: [_sort_key(v) for v in t])
    return sorted(values, key=_sort_key)


def _group_label(group: tuple, names: Sequence[str]) -> str:
    return ", ".join(f"{_label(k)} = {v}" for k, v in zip(names, group)) or "all runs"


def _plot(metric: str, x: str, others: list[str], rows: list[dict], size_col: str | None):
    """One figure of ``metric`` against ``x``: median and IQR over the remaining rows per group."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    xs = _order(r[x] for r in rows)
    numeric = all(_is_number(v) for v in xs)
    pos = {v: (float(v) if numeric else i) for i, v in enumerate(xs)}
    groups = _order(tuple(r[o] for o in others) for r in rows) if others else [()]
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    fits: list[tuple[str, Fit]] = []
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for gi, group in enumerate(groups):
        color = colors[gi % len(colors)]
        mine = [r for r in rows if tuple(r[o] for o in others) == group and _is_number(r.get(metric))]
        if not mine:
            continue
        at, med, lo, hi = [], [], [], []
        for v in xs:
            ys = np.array([r[metric] for r in mine if r[x] == v], float)
            if ys.size:
                at.append(pos[v])
                q1, q2, q3 = np.percentile(ys, [25, 50, 75])
                med.append(q2), lo.append(q1), hi.append(q3)
        label = _group_label(group, others) if others else "median over seeds"
        if numeric:
            ax.plot(at, med, "o-", color=color, label=label)
            if any(h > l for h, l in zip(hi, lo)):
                ax.fill_between(at, lo, hi, color=color, alpha=0.2, linewidth=0)
        else:  # categories: no line between them; the interquartile range as an error bar, groups side by side
            shift = 0.1 * (gi - (len(groups) - 1) / 2)
            ax.errorbar(np.array(at) + shift, med, yerr=[np.subtract(med, lo), np.subtract(hi, med)], fmt="o",
                        color=color, capsize=3, label=label)
        if numeric and x in SIZES and (metric in FIT_BOTH or metric in FIT_POWER):
            n = [r[size_col] if size_col and _is_number(r.get(size_col)) else r[x] for r in mine]
            y = [r[metric] for r in mine]
            kinds = (fit_log, fit_power) if metric in FIT_BOTH else (fit_power,)
            grid = np.geomspace(min(at), max(at), 60) if min(at) > 0 else None
            for kind, style in zip(kinds, ("--", ":")):
                f = kind(n, y)
                if f is None or grid is None:
                    continue
                fits.append((label, f))
                ax.plot(grid, f(grid), style, color=color, linewidth=1,
                        label=f"{f.formula(_short(metric))} (R² {f.r2:.3f})")
    ax.set_xlabel(_label(x))
    ax.set_ylabel(_label(metric))
    _readable_y(ax, [r[metric] for r in rows if _is_number(r.get(metric))])
    if numeric:
        if min(xs) > 0 and max(xs) / min(xs) >= 8:
            ax.set_xscale("log")
            _plain_ticks(ax.xaxis, at=[float(v) for v in xs])
        if metric in FIT_POWER and x in SIZES and all(_is_number(r.get(metric)) and r[metric] > 0 for r in rows):
            ax.set_yscale("log")
            _plain_ticks(ax.yaxis)
    else:
        ax.set_xticks(range(len(xs)), [str(v) for v in xs])
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, frameon=False)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    return buf.getvalue(), fits


def _plain_ticks(axis, at: list[float] | None = None) -> None:
    """Plain numbers (1,000; 0.5; 20) on a logarithmic ``axis``, at ``at`` or at 1-2-5 steps."""
    from matplotlib.ticker import FixedLocator, FuncFormatter, LogLocator, NullFormatter

    axis.set_major_locator(FixedLocator(at) if at else LogLocator(subs=(1.0, 2.0, 5.0)))
    axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:,.0f}" if v >= 100 else f"{v:g}"))
    axis.set_minor_formatter(NullFormatter())


def _readable_y(ax, values: list[float]) -> None:
    """No offset notation (``1e-6 + 1.647e-2``); a spread below 0.1 % of the values is drawn flat."""
    if not values:
        return
    ax.ticklabel_format(axis="y", useOffset=False, style="plain")
    lo, hi = min(values), max(values)
    centre = (lo + hi) / 2
    if hi - lo <= 1e-3 * abs(centre):
        pad = 0.05 * abs(centre) or 1.0
        ax.set_ylim(centre - pad, centre + pad)


def _short(metric: str) -> str:
    short = {"messages_per_module": "messages/module", "seconds": "t", "cpu_seconds": "t", "solve_cpu_seconds": "t"}
    return short.get(metric, metric)


def _figures(params: list[str], metrics: list[str], ok: list[dict], out: Path) -> list[Figure]:
    swept = [p for p in params if p not in SEEDS and len({json.dumps(r[p]) for r in ok}) > 1]
    size_col = "n_modules" if any(_is_number(r.get("n_modules")) for r in ok) else None
    figures = []
    for metric in metrics:
        if metric in NOT_PLOTTED or not any(_is_number(r.get(metric)) for r in ok):
            continue
        for x in swept:
            others = [p for p in swept if p != x]
            png, fits = _plot(metric, x, others, ok, size_col if x == "n" else None)
            path = out / f"{metric}_vs_{x}.png"
            spread = "seeds" if any(len({r[s] for r in ok}) > 1 for s in SEEDS if ok and s in ok[0]) else "runs"
            caption = (f"{_label(metric)} against {_label(x)}: median over {spread} and interquartile "
                       f"range" + (f", one line per {', '.join(_label(o) for o in others)}" if others else ""))
            figures.append(Figure(path, f"{_label(metric)} vs {_label(x)}", caption, png, fits))
    return figures


def _table(head: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    th = "".join(f"<th>{html.escape(str(h))}</th>" for h in head)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(_fmt(v))}</td>" for v in r) + "</tr>" for r in rows)
    return f"<table><thead><tr>{th}</tr></thead><tbody>{body}</tbody></table>"


def _fmt(v: Any) -> str:
    if v is None:
        return "—"
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def _summary_rows(params: list[str], metrics: list[str], ok: list[dict]) -> tuple[list[str], list[list]]:
    """Median of every metric per combination of the non-seed parameters."""
    keys = [p for p in params if p not in SEEDS]
    shown = [m for m in metrics if any(_is_number(r.get(m)) for r in ok)]
    out = []
    for combo, rs in itertools.groupby(sorted(ok, key=lambda r: [_sort_key(r[k]) for k in keys]),
                                       key=lambda r: tuple(r[k] for k in keys)):
        rs = list(rs)
        meds = []
        for m in shown:
            ys = [r[m] for r in rs if _is_number(r.get(m))]
            meds.append(float(np.median(ys)) if ys else None)
        out.append([*combo, len(rs), *meds])
    return [*keys, "runs", *(_label(m) for m in shown)], out


_CSS = """body{font-family:system-ui,sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;color:#222}
table{border-collapse:collapse;margin:1em 0;font-size:0.9em}
td,th{border:1px solid #ccc;padding:3px 8px;text-align:right}
th{background:#f3f3f3}figure{display:inline-block;margin:0.5em;vertical-align:top;max-width:680px}
figcaption{font-size:0.85em;color:#444}pre{background:#f7f7f7;padding:0.8em;overflow-x:auto}img{max-width:100%}"""


def write_report(directory: str | Path) -> ReportResult:
    """Write ``directory/report.html`` and its PNG figures from ``directory/study.sqlite`` alone."""
    directory = Path(directory)
    facts, runs, invocations = read_runs(directory / DB_NAME)
    params, metrics = _columns(facts, runs)
    ok = [r for r in runs if r.get("status") == "ok"]
    failed = [r for r in runs if r.get("status") != "ok"]
    figures = _figures(params, metrics, ok, directory)
    name = facts.get("name") or directory.name
    parts = [f"<h1>Study: {html.escape(name)}</h1>",
             f"<p>{len(runs)} cells in the store: {len(ok)} ok, {len(failed)} failed"
             + (f"; command <code>{html.escape(facts['command'])}</code>" if "command" in facts else "") + ".</p>"]
    if figures:
        parts.append("<h2>Figures</h2>")
    for fig in figures:
        data = base64.b64encode(fig.png).decode()
        parts.append(f"<figure><img alt=\"{html.escape(fig.title)}\" src=\"data:image/png;base64,{data}\">"
                     f"<figcaption>{html.escape(fig.caption)} ({html.escape(fig.path.name)})</figcaption></figure>")
    fits = [(fig, label, f) for fig in figures for label, f in fig.fits]
    if fits:
        parts.append("<h2>Fits</h2>")
        parts.append(_table(["quantity", "series", "fit", "R²", "samples"],
                            [[_label(fig.path.stem.split("_vs_")[0]), label, f.formula(), f.r2, f.points]
                             for fig, label, f in fits]))
    if ok:
        head, rows = _summary_rows(params, metrics, ok)
        parts.append("<h2>Medians per setting</h2>" + _table(head, rows))
    if failed:
        parts.append("<h2>Failed cells</h2>" + _table([*params, "error"],
                                                       [[r.get(p) for p in params] + [r.get("error")]
                                                        for r in failed[:200]]))
    if invocations:
        parts.append("<h2>Provenance</h2>" + _table(
            ["invocation", "started", "finished", "engine", "workers", "git revision", "python", "cells run", "failed"],
            [[s.get("id"), s.get("started"), s.get("finished"), s.get("engine"), s.get("workers"),
              s.get("git_revision"), s.get("python"), s.get("cells_run"), s.get("cells_failed")] for s in invocations]))
        packages = invocations[-1].get("packages")
        if packages:
            parts.append("<p>Packages (last invocation): " + html.escape(
                ", ".join(f"{k} {v}" for k, v in json.loads(packages).items())) + "</p>")
    if facts.get("spec"):
        parts.append("<h2>Specification</h2><pre>" + html.escape(facts["spec"]) + "</pre>")
    page = (f"<!DOCTYPE html><html><head><meta charset=\"utf-8\"><title>{html.escape(name)}</title>"
            f"<style>{_CSS}</style></head><body>{''.join(parts)}</body></html>\n")
    for fig in figures:
        write_atomic(fig.path, lambda fh, png=fig.png: fh.write(png), binary=True)
    target = directory / "report.html"
    write_atomic(target, lambda fh: fh.write(page))
    return ReportResult(target, tuple(f.path for f in figures), len(runs), len(failed))
