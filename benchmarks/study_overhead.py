"""Overhead of the study runner per cell, against calling the library directly in the same run.

Workload: ``localize`` cells (the ``multi`` scenario with 2 assemblies, centralized windowed
estimator), each a different seed, sized by their number of steps so that one cell takes about
``--durations`` seconds when called directly (calibrated at the start of the run). For each
duration the same cells are run

- directly: :func:`sims.study.cells.run_cell` in this process, one after the other (the reference,
  measured before and after the engines, and averaged, so a drifting machine load hits both sides);
- as a study on the local pool (``--workers``, 1 by default so that it compares with the serial
  reference), pool start-up, result transfer and one SQLite transaction per row included;
- as a study on Ray (a local instance with ``--workers`` CPUs, started before the clock: the setting
  of a running cluster; its start-up time is reported on its own).

Reported per engine and duration: the study's wall time against the direct one (ratio, overhead in %
and per cell), and the steady-state overhead per cell (the time between consecutive rows minus the
cell's own time, median over cells after the first: what each further cell costs beyond its work).
Target: under 5 % for 2 s cells on the local pool.

Usage::

    python benchmarks/study_overhead.py [--out out/benchmarks] [--durations 0.1 2] [--cells 10]
        [--workers 1] [--engines local ray]

Writes ``OUT/study_overhead.json`` and prints a summary table.
"""

from __future__ import annotations

import _common  # noqa: F401  (pins BLAS threads before numpy loads)

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from _common import machine
from sims.io.atomic import write_json_atomic
from sims.study.cells import run_cell
from sims.study.engines import LocalEngine, RayEngine
from sims.study.runner import run_study
from sims.study.spec import parse_spec

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
        import sqlite3

        with sqlite3.connect(Path(tmp) / "study.sqlite") as con:
            seconds = [r[0] for r in con.execute("SELECT seconds FROM runs ORDER BY id")]
    if result.failed:
        raise RuntimeError(f"{result.failed} cells failed")
    gaps = [b - a - s for a, b, s in zip(marks[1:-1], marks[2:], seconds[1:])]
    return {"wall_seconds": wall, "cell_seconds_in_workers": sum(seconds),
            "first_row_after_seconds": marks[1] - start if len(marks) > 1 else None,
            "steady_overhead_per_cell_seconds": statistics.median(gaps) if gaps else None}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out/benchmarks"),
                        help="output folder (default out/benchmarks)")
    parser.add_argument("--durations", type=float, nargs="+", default=[0.1, 2.0], help="target seconds per cell")
    parser.add_argument("--cells", type=int, default=10, help="cells per study (default 10)")
    parser.add_argument("--workers", type=int, default=1, help="workers of the local pool and CPUs of Ray (default 1)")
    parser.add_argument("--engines", nargs="+", choices=("local", "ray"), default=["local", "ray"])
    args = parser.parse_args(argv)
    if args.cells < 3 or args.workers < 1:
        parser.error("--cells must be >= 3 and --workers >= 1")
    payload = {"machine": machine(), "cells": args.cells, "workers": args.workers, "workload": BASE, "runs": []}
    ray = None
    if "ray" in args.engines:
        import ray

        start = time.perf_counter()
        ray.init(num_cpus=args.workers, include_dashboard=False, log_to_driver=False, logging_level="ERROR")
        payload["ray_init_seconds"] = time.perf_counter() - start
    try:
        for target in args.durations:
            steps = calibrate(target)
            before = direct(steps, args.cells)
            engines = {name: as_study(LocalEngine(args.workers) if name == "local" else RayEngine(), steps, args.cells)
                       for name in args.engines}
            after = direct(steps, args.cells)
            reference = (before + after) / 2
            for name, got in engines.items():
                # with w workers the study can be up to w times faster than the serial reference
                ideal = reference / args.workers
                row = {"target_cell_seconds": target, "steps": steps, "engine": name,
                       "direct_seconds": reference, "direct_seconds_before_after": [before, after], **got,
                       "ratio_to_direct": got["wall_seconds"] / ideal,
                       "overhead_pct": 100 * (got["wall_seconds"] / ideal - 1),
                       "overhead_per_cell_seconds": (got["wall_seconds"] - ideal) / args.cells * args.workers}
                payload["runs"].append(row)
                print(f"{target:5.1f} s cells ({steps} steps), {name:5s}: direct {reference:6.2f} s, study "
                      f"{got['wall_seconds']:6.2f} s -> overhead {row['overhead_pct']:+5.1f} % "
                      f"({row['overhead_per_cell_seconds'] * 1e3:+.0f} ms/cell; steady "
                      f"{got['steady_overhead_per_cell_seconds'] * 1e3:+.0f} ms/cell)", flush=True)
    finally:
        if ray is not None:
            ray.shutdown()
    payload["machine"]["loadavg_end"] = list(__import__("os").getloadavg())
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "study_overhead.json"
    write_json_atomic(path, payload)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
