"""Overhead of the study runner per cell, against calling the library directly in the same run.

Workload: ``localize`` cells (the ``multi`` scenario with 2 assemblies, centralized windowed
estimator), each a different seed, sized by their number of steps so that one cell takes about
``--durations`` seconds when called directly (calibrated at the start of the run). For each
duration the same cells are run

- directly: :func:`sims.lab.study.cells.run_cell` in this process, one after the other (the reference,
  measured before and after the engines, and averaged, so a drifting machine load hits both sides);
- as a study on the local pool (``--workers``, 1 by default so that it compares with the serial
  reference), pool start-up, result transfer and one SQLite transaction per row included;
- as a study on Ray (a local instance with ``--workers`` CPUs, started before the clock: the setting
  of a running cluster; its start-up time is reported on its own).

Reported per engine and duration, as medians over ``--repeats`` (engines alternate order between
repeats): the study's wall time against the direct one (ratio, overhead in % and per cell), the
time to the first row (worker start-up: a fresh interpreter importing the library and building its
per-process caches), the wall time spent outside the cells against the cells' own time in the
workers (what the runner itself costs, apart from cells running slower or faster in a worker than
in this process), and the steady-state overhead per cell (the time between consecutive rows
minus the cell's own time, median over cells after the first: what each further cell costs beyond
its work). Target: under 5 % for 2 s cells on the local pool.

Usage::

    python benchmarks/study_overhead.py [--out out/benchmarks] [--durations 0.1 2] [--cells 10]
        [--workers 1] [--engines local ray] [--repeats 3]

Writes ``OUT/study_overhead.json`` and prints a summary table.
"""

from __future__ import annotations

import _common  # noqa: F401  (pins BLAS threads before numpy loads)

import sqlite3
import statistics
import tempfile
import time
from pathlib import Path

from _common import machine, parser, save
from sims.lab.study.cells import run_cell
from sims.lab.study.engines import LocalEngine, RayEngine
from sims.lab.study.runner import run_study
from sims.lab.study.spec import parse_spec

BASE = {"scenario": "multi", "n_assemblies": 2, "mode": "centralized", "window": 5}


def _params(steps: int, seed: int) -> dict:
    return {**BASE, "steps": steps, "seed": seed}


def calibrate(target: float) -> int:
    """Steps that make one cell take about ``target`` seconds when called directly."""
    steps = 10
    for _ in range(4):
        start = time.perf_counter()
        run_cell("localize", _params(steps, 0))
        took = time.perf_counter() - start
        new = max(2, round(steps * target / took))
        if abs(new - steps) <= max(1, 0.05 * steps):
            return new
        steps = new
    return steps


def spec_text(steps: int, cells: int) -> str:
    fixed = "\n".join(f"{k} = {v!r}".replace("'", '"') for k, v in {**BASE, "steps": steps}.items())
    return (f'name = "overhead-{steps}-steps"\ncommand = "localize"\n[fixed]\n{fixed}\n'
            f"[grid]\nseed = {list(range(cells))}\n")


def direct(steps: int, cells: int) -> float:
    """Wall time of the cells called one after the other in this process."""
    start = time.perf_counter()
    for seed in range(cells):
        run_cell("localize", _params(steps, seed))
    return time.perf_counter() - start


def as_study(engine, steps: int, cells: int) -> dict:
    """Wall time of the same cells as a study on ``engine``, and the per-cell steady-state overhead."""
    marks: list[float] = []
    with tempfile.TemporaryDirectory() as tmp:
        spec = parse_spec(spec_text(steps, cells))
        start = time.perf_counter()
        result = run_study(spec, tmp, engine, progress=lambda done, total, **_: marks.append(time.perf_counter()))
        wall = time.perf_counter() - start
        with sqlite3.connect(Path(tmp) / "study.sqlite") as con:
            seconds = [r[0] for r in con.execute("SELECT seconds FROM runs ORDER BY id")]
    if result.failed:
        raise RuntimeError(f"{result.failed} cells failed")
    gaps = [b - a - s for a, b, s in zip(marks[1:-1], marks[2:], seconds[1:])]
    return {"wall_seconds": wall, "cell_seconds_in_workers": sum(seconds),
            "first_row_after_seconds": marks[1] - start if len(marks) > 1 else None,
            "steady_overhead_per_cell_seconds": statistics.median(gaps) if gaps else None}


def _row(target: float, steps: int, repeat: int, name: str, direct_runs: tuple, got: dict, args) -> dict:
    reference = sum(direct_runs) / 2
    ideal = reference / args.workers  # with w workers the study can be up to w times faster than the serial reference
    row = {"target_cell_seconds": target, "steps": steps, "repeat": repeat, "engine": name,
           "direct_seconds": reference, "direct_seconds_before_after": list(direct_runs), **got,
           "ratio_to_direct": got["wall_seconds"] / ideal, "overhead_pct": 100 * (got["wall_seconds"] / ideal - 1),
           "overhead_per_cell_seconds": (got["wall_seconds"] - ideal) / args.cells * args.workers,
           # the wall time not spent inside cells (start-up, transfer, store), against the cells' own time
           "outside_cells_pct": 100 * (got["wall_seconds"] * args.workers / got["cell_seconds_in_workers"] - 1)}
    print(f"{target:5.1f} s cells ({steps} steps), {name:5s} #{repeat}: direct {reference:6.2f} s, study "
          f"{got['wall_seconds']:6.2f} s -> overhead {row['overhead_pct']:+5.1f} % "
          f"(steady {got['steady_overhead_per_cell_seconds'] * 1e3:+.0f} ms/cell)", flush=True)
    return row


def _summary(runs: list[dict]) -> list[dict]:
    """Medians over the repeats, per cell duration and engine."""
    out = []
    keys = sorted({(r["target_cell_seconds"], r["engine"]) for r in runs})
    for target, engine in keys:
        mine = [r for r in runs if (r["target_cell_seconds"], r["engine"]) == (target, engine)]
        row = {"target_cell_seconds": target, "engine": engine, "repeats": len(mine)}
        for field in ("direct_seconds", "wall_seconds", "cell_seconds_in_workers", "ratio_to_direct", "overhead_pct",
                      "overhead_per_cell_seconds", "steady_overhead_per_cell_seconds", "first_row_after_seconds",
                      "outside_cells_pct"):
            row[f"{field}_median"] = statistics.median(r[field] for r in mine)
        out.append(row)
    return out


def main(argv=None) -> int:
    ap = parser(__doc__)
    ap.add_argument("--durations", type=float, nargs="+", default=[0.1, 2.0], help="target seconds per cell")
    ap.add_argument("--cells", type=int, default=10, help="cells per study (default 10)")
    ap.add_argument("--workers", type=int, default=1, help="workers of the local pool and CPUs of Ray (default 1)")
    ap.add_argument("--engines", nargs="+", choices=("local", "ray"), default=["local", "ray"])
    ap.add_argument("--repeats", type=int, default=3, help="repeats of the whole comparison (default 3)")
    args = ap.parse_args(argv)
    if args.cells < 3 or args.workers < 1 or args.repeats < 1:
        ap.error("--cells must be >= 3, --workers and --repeats >= 1")
    payload = {"benchmark": "study_overhead", "machine": machine(), "cells": args.cells, "workers": args.workers, "workload": BASE, "runs": []}
    ray = None
    if "ray" in args.engines:
        import ray

        start = time.perf_counter()
        ray.init(num_cpus=args.workers, include_dashboard=False, log_to_driver=False, logging_level="ERROR")
        payload["ray_init_seconds"] = time.perf_counter() - start
    try:
        for target in args.durations:
            steps = calibrate(target)
            for repeat in range(args.repeats):
                # direct, then each engine, then direct again: both sides see the same drift of the load
                before = direct(steps, args.cells)
                order = args.engines if repeat % 2 == 0 else list(reversed(args.engines))
                engines = {name: as_study(LocalEngine(args.workers) if name == "local" else RayEngine(), steps,
                                          args.cells) for name in order}
                after = direct(steps, args.cells)
                for name, got in engines.items():
                    payload["runs"].append(_row(target, steps, repeat, name, (before, after), got, args))
        payload["summary"] = _summary(payload["runs"])
        for row in payload["summary"]:
            print(f"{row['target_cell_seconds']:4.1f} s cells, {row['engine']:5s}: study / direct "
                  f"{row['ratio_to_direct_median']:.3f} (overhead {row['overhead_pct_median']:+.1f} %, "
                  f"{row['overhead_per_cell_seconds_median'] * 1e3:+.0f} ms/cell; outside cells "
                  f"{row['outside_cells_pct_median']:+.1f} %), steady "
                  f"{row['steady_overhead_per_cell_seconds_median'] * 1e3:+.1f} ms/cell, first row after "
                  f"{row['first_row_after_seconds_median']:.2f} s", flush=True)
    finally:
        if ray is not None:
            ray.shutdown()
    save("study_overhead", payload, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
