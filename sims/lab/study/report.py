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
import json
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

from sims.io.atomic import write_atomic
from sims.lab.study.fits import Fit
from sims.lab.study.plots import plot_metric
from sims.lab.study.store import BOOKKEEPING, DB_NAME, read_runs
from sims.lab.study.summary import (STEADY_RTOL, Steady, collapse_constant_columns, fmt, is_number, medians_per_setting,
                                order, steady)

__all__ = ["Figure", "Plan", "ReportResult", "plan", "write_report", "LABELS"]

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
#: metrics that are not worth a figure of their own (they follow the size parameter)
NOT_PLOTTED = ("n_modules", "observations")


def _label(name: str) -> str:
    return LABELS.get(name, name.replace("_", " "))


@dataclass
class Figure:
    """One figure of the report: its file, the metric and parameter it draws, and its fits."""

    path: Path
    metric: str
    x: str
    png: bytes
    fits: list[tuple[str, Fit]] = field(default_factory=list)


@dataclass(frozen=True)
class ReportResult:
    """What :func:`write_report` wrote."""

    html: Path
    figures: tuple[Path, ...]
    rows: int
    failed: int


@dataclass(frozen=True)
class Plan:
    """What the report shows, decided from the rows alone (see :func:`plan`).

    Attributes
    ----------
    stated : list of Steady
        Parameters and metrics the same (or within ``STEADY_RTOL``) in every 'ok' run: said once.
    replicates : dict
        Seed column -> its distinct values (the spread of every point).
    swept : list of str
        Parameters with several values (seeds excluded): the table's keys.
    axes : list of str
        The swept parameters figures are drawn against (the numeric ones if any, else all).
    plotted : list of str
        Metrics that vary: one figure per metric and axis.
    params : tuple of str
        Every parameter column.
    """

    stated: list[Steady]
    replicates: dict[str, list]
    swept: list[str]
    axes: list[str]
    plotted: list[str]
    params: tuple[str, ...] = ()


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


def plan(params: Sequence[str], metrics: Sequence[str], ok: Sequence[dict]) -> Plan:
    """Decide what is said once, what is swept, and what is plotted against what.

    A parameter with one value among the 'ok' rows and a metric that :func:`steady` finds constant
    (or within ``STEADY_RTOL``) are stated; seeds are replicates; the rest is swept or plotted.
    """
    stated, replicates, swept = [], {}, []
    for p in params:
        values = [r.get(p) for r in ok]
        distinct = order(values)
        if p in SEEDS and len(distinct) > 1:
            replicates[p] = distinct
        elif len(distinct) <= 1:
            stated.append(Steady(p, distinct[0] if distinct else None))
        else:
            swept.append(p)
    plotted = []
    for m in metrics:
        s = steady(m, [r.get(m) for r in ok]) if ok else None
        if s is not None:
            stated.append(s)
        elif m not in NOT_PLOTTED and any(is_number(r.get(m)) for r in ok):
            plotted.append(m)
    numeric = [p for p in swept if all(is_number(r.get(p)) for r in ok)]
    return Plan(stated, replicates, swept, numeric or list(swept), plotted, tuple(params))


def _figures(p: Plan, ok: list[dict], out: Path) -> list[Figure]:
    size_col = "n_modules" if any(is_number(r.get("n_modules")) for r in ok) else None
    figures = []
    for x in p.axes:
        others = [s for s in p.swept if s != x]
        for metric in p.plotted:
            png, fits = plot_metric(metric, x, others, ok, _label, size_col if x == "n" else None)
            figures.append(Figure(out / f"{metric}_vs_{x}.png", metric, x, png, fits))
    return figures


def _show(name: str, value: Any) -> str:
    """A parameter's value as text (a path as written: two logs may share a file name)."""
    return fmt(value)


def _table(head: Sequence[str], rows: Sequence[Sequence[Any]], text_cols: Sequence[int] = ()) -> str:
    def cls(i: int) -> str:
        return ' class="text"' if i in text_cols else ""

    th = "".join(f"<th{cls(i)}>{html.escape(str(h))}</th>" for i, h in enumerate(head))
    body = "".join("<tr>" + "".join(f"<td{cls(i)}>{html.escape(v if isinstance(v, str) and i in text_cols else fmt(v))}"
                                    "</td>" for i, v in enumerate(r)) + "</tr>" for r in rows)
    return f'<div class="scroll"><table><thead><tr>{th}</tr></thead><tbody>{body}</tbody></table></div>'


def _stated_html(p: Plan, n_ok: int) -> str:
    if not p.stated:
        return ""
    rows = []
    for title, group in (("settings", [s for s in p.stated if s.name in p.params]),
                         ("results", [s for s in p.stated if s.name not in p.params])):
        if group:
            rows.append(f"<tr><td class=\"group text\" colspan=\"2\">{title}</td></tr>")
        for s in group:
            value = _show(s.name, s.value) if s.exact and s.value is not None else s.describe()
            rows.append(f"<tr><th class=\"text\">{html.escape(_label(s.name))}</th><td class=\"text\">"
                        f"{html.escape(value)}</td></tr>")
    return (f"<h2>The same in every run</h2><p>These did not change across the {n_ok} successful runs "
            f"(metrics within ±{100 * STEADY_RTOL / 2:g} % are given with their range), so they are stated "
            "here once and not plotted.</p>"
            f'<table class="facts"><tbody>{"".join(rows)}</tbody></table>')


def _spread_sentence(p: Plan, ok: list[dict]) -> str:
    if p.replicates:
        seeds = "; ".join(f"{len(v)} values of {k}" for k, v in p.replicates.items())
        per = "the replicates"
    else:
        seeds, per = "", "the runs"
    text = (f"Each figure shows the median over {per} at each point (line), their interquartile range (band, "
            "or bars between categories) and every run (dots)")
    text += f" ({seeds})." if seeds else "."
    return text + " Linear y axes start at zero, so a change is drawn at its true size."


def _description(facts: dict) -> str:
    try:
        return str(tomllib.loads(facts.get("spec", "")).get("description", "")).strip()
    except (tomllib.TOMLDecodeError, AttributeError):
        return ""


_CSS = """body{font-family:system-ui,sans-serif;max-width:1200px;margin:1.5em auto;padding:0 16px;color:#222;
line-height:1.45}h1{font-size:1.6em;margin-bottom:.2em}h2{font-size:1.25em;margin-top:1.6em;border-bottom:1px solid #ddd}
h3{font-size:1.05em;margin:1em 0 .3em}p{max-width:60em}
.grid{display:grid;grid-template-columns:repeat(auto-fill,minmax(360px,1fr));gap:6px 18px;align-items:start}
figure{margin:0}figure img{width:100%;height:auto;display:block}figcaption{font-size:.75em;color:#777}
.scroll{overflow-x:auto;max-width:100%}table{border-collapse:collapse;margin:.6em 0;font-size:.85em;
font-variant-numeric:tabular-nums}td,th{border-bottom:1px solid #e2e2e2;padding:3px 9px;text-align:right}
thead th{background:#f4f4f4;vertical-align:bottom;max-width:9em;white-space:normal}
.text{text-align:left}table.facts th{font-weight:600;padding-right:1.5em}
.group{font-style:italic;color:#666;padding-top:.6em}.note{color:#555;font-size:.9em}pre{background:#f7f7f7;padding:.8em;overflow-x:auto;font-size:.85em}"""


def write_report(directory: str | Path) -> ReportResult:
    """Write ``directory/report.html`` and its PNG figures from ``directory/study.sqlite`` alone."""
    directory = Path(directory)
    facts, runs, invocations = read_runs(directory / DB_NAME)
    params, metrics = _columns(facts, runs)
    ok = [r for r in runs if r.get("status") == "ok"]
    failed = [r for r in runs if r.get("status") != "ok"]
    p = plan(params, metrics, ok)
    figures = _figures(p, ok, directory)
    name = facts.get("name") or directory.name
    intro = f"{len(runs)} cells in the store: {len(ok)} ok, {len(failed)} failed"
    degraded = sum(r.get("run_status") == "degraded" for r in ok)
    if degraded:  # finished with metrics, but some step's window did not converge (sims.runners.run_status)
        intro += f" ({degraded} of the ok cells ran degraded: some step did not converge)"
    if "command" in facts:
        intro += f"; each cell runs <code>{html.escape(facts['command'])}</code>"
    parts = [f"<h1>Study: {html.escape(name)}</h1>"]
    if _description(facts):
        parts.append(f"<p>{html.escape(_description(facts))}</p>")
    parts.append(f"<p>{intro}.</p>")
    parts.append(_stated_html(p, len(ok)))
    if figures:
        parts.append(f"<h2>Figures</h2><p class=\"note\">{html.escape(_spread_sentence(p, ok))}</p>")
    for x in p.axes:
        mine = [f for f in figures if f.x == x]
        others = [s for s in p.swept if s != x]
        title = f"Against {_label(x)}" + (f", one colour per {', '.join(_label(o) for o in others)}" if others else "")
        parts.append(f"<h3>{html.escape(title)}</h3><div class=\"grid\">")
        for fig in mine:
            data = base64.b64encode(fig.png).decode()
            parts.append(f"<figure><img alt=\"{html.escape(_label(fig.metric))} against {html.escape(_label(x))}\" "
                         f"src=\"data:image/png;base64,{data}\"><figcaption>{html.escape(fig.path.name)}"
                         "</figcaption></figure>")
        parts.append("</div>")
    fits = [(fig, label, f) for fig in figures for label, f in fig.fits]
    if fits:
        parts.append("<h2>Fits</h2>")
        parts.append(_table(["quantity", "series", "fit", "R²", "samples"],
                            [[_label(fig.metric), label, f.formula(), f.r2, f.points] for fig, label, f in fits],
                            text_cols=(0, 1, 2)))
    if ok:
        parts.append(_medians_html(p, metrics, ok))
    if failed:
        shown = [q for q in params if len({json.dumps(r.get(q)) for r in failed}) > 1] or params[:1]
        parts.append(f"<h2>Failed cells</h2>" + _table(
            [*shown, "error"], [[_show(q, r.get(q)) for q in shown] + [r.get("error") or ""] for r in failed[:200]],
            text_cols=tuple(range(len(shown) + 1))))
    if invocations:
        parts.append(_provenance_html(invocations))
    if facts.get("spec"):
        parts.append("<h2>Specification</h2><pre>" + html.escape(facts["spec"]) + "</pre>")
    page = (f"<!DOCTYPE html><html><head><meta charset=\"utf-8\"><meta name=\"viewport\" "
            f"content=\"width=device-width\"><title>{html.escape(name)}</title>"
            f"<style>{_CSS}</style></head><body>{''.join(parts)}</body></html>\n")
    for fig in figures:
        write_atomic(fig.path, lambda fh, png=fig.png: fh.write(png), binary=True)
    target = directory / "report.html"
    write_atomic(target, lambda fh: fh.write(page))
    return ReportResult(target, tuple(f.path for f in figures), len(runs), len(failed))


def _medians_html(p: Plan, metrics: Sequence[str], ok: list[dict]) -> str:
    stated = {s.name for s in p.stated}
    shown = [m for m in metrics if m not in stated and any(is_number(r.get(m)) for r in ok)]
    head, rows = medians_per_setting(p.swept, shown, ok)
    head, rows, constants = collapse_constant_columns(head, rows, keep=len(p.swept))
    also = [(c, v) for c, v in constants if c not in stated]
    text = "<h2>Medians per setting</h2>"
    if p.replicates or len(ok) > len(rows):
        text += "<p class=\"note\">The median over the runs of each setting; <i>runs</i> counts them.</p>"
    if also:
        text += ("<p class=\"note\">The same in every row: " + html.escape(
            "; ".join(f"{_label(c)} {fmt(v)}" for c, v in also)) + ".</p>")
    labels = [_label(h) if h not in p.swept else h for h in head]
    return text + _table(labels, rows, text_cols=tuple(i for i, h in enumerate(head) if h in p.swept
                                                       and not all(is_number(r[i]) for r in rows)))


def _provenance_html(invocations: list[dict]) -> str:
    rows = [[s.get("id"), (s.get("started") or "").replace("T", " ")[:19], (s.get("finished") or "").replace("T", " ")[:19],
             s.get("status") or "", s.get("engine"), s.get("workers"), s.get("host") or "",
             (s.get("git_revision") or "")[:12] + ("+modified" if (s.get("git_revision") or "").endswith("+modified") else ""),
             s.get("python"), s.get("cells_run"), s.get("cells_failed")] for s in invocations]
    text = "<h2>Provenance</h2>" + _table(
        ["run", "started (UTC)", "finished", "status", "engine", "workers", "host", "git revision", "python",
         "cells run", "failed"], rows, text_cols=(1, 2, 3, 4, 6, 7, 8))
    packages = invocations[-1].get("packages")
    if packages:
        text += "<p class=\"note\">Packages (last run): " + html.escape(
            ", ".join(f"{k} {v}" for k, v in json.loads(packages).items())) + "</p>"
    return text
