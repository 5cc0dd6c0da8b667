"""Time to the first row of a study on Ray, as ``decentral study --engine ray`` runs it (a fresh local instance).

Each repeat runs the same tiny study (``--cells`` ensemble cells of 60 modules, ~0.1 s each) into a
new store with :class:`sims.lab.study.engines.RayEngine` starting its own Ray instance with
``--workers`` CPUs, in two ways, alternating which goes first:

- ``per_task_env`` (the reference): the pinned BLAS environment given to every task, which makes
  Ray start a dedicated worker process for the study's tasks;
- ``inherited_env`` (the default): the environment set when the instance starts, which its
  workers inherit, so the workers Ray starts with the instance take the first cells.

Reported per way (medians over ``--repeats``): ``ray.init`` wall time, the time from the start of
the study to its first row (``ray.init`` included), the same after ``ray.init`` (what the way
changes), the time to the last row, and the ratios of the first-row times (reference / default). Wall times on this machine, with its load average beside them.

Usage::

    python benchmarks/study_ray_latency.py [--out out/benchmarks] [--repeats 3] [--cells 4] [--workers 2]

Writes ``OUT/study_ray_latency.json``.
"""

from __future__ import annotations

import _common  # noqa: F401  (pins BLAS threads before numpy loads)

import os
import statistics
import tempfile
import time
from pathlib import Path

from _common import machine, parser, save

SPEC = """
name = "first-row"
command = "ensemble"
[fixed]
shape = "triple"
n = 60
[grid]
seed = {seeds}
"""


def one_study(per_task_env: bool, cells: int, workers: int) -> dict:
    """Run the tiny study once on a fresh Ray instance; the timings of this run."""
    import ray

    from sims.lab.study.engines import RayEngine
    from sims.lab.study.runner import run_study
    from sims.lab.study.spec import parse_spec

    spec = parse_spec(SPEC.format(seeds=list(range(cells))))
    engine = RayEngine(None, workers)
    engine.per_task_env = per_task_env
    marks: dict[str, float] = {}
    real_init = ray.init

    def timed_init(*args, **kwargs):
        t0 = time.perf_counter()
        out = real_init(*args, **kwargs)
        marks["init"] = time.perf_counter() - t0
        return out

    def progress(done: int, total: int, failed: int = 0) -> None:
        now = time.perf_counter()
        if done == 1:
            marks["first_row"] = now - marks["start"]
        if done == total:
            marks["last_row"] = now - marks["start"]

    ray.init = timed_init
    try:
        with tempfile.TemporaryDirectory() as tmp:
            marks["start"] = time.perf_counter()
            result = run_study(spec, Path(tmp), engine, progress=progress)
    finally:
        ray.init = real_init
    assert result.failed == 0, "a cell failed"
    return {"ray_init_s": marks["init"], "first_row_s": marks["first_row"],
            "first_row_after_init_s": marks["first_row"] - marks["init"], "last_row_s": marks["last_row"],
            "loadavg_1min": os.getloadavg()[0]}


def main() -> None:
    ap = parser(__doc__)
    ap.add_argument("--repeats", type=int, default=3, help="repeats of each way (default 3)")
    ap.add_argument("--cells", type=int, default=4, help="cells per study (default 4)")
    ap.add_argument("--workers", type=int, default=2, help="CPUs of the Ray instance (default 2)")
    args = ap.parse_args()
    info = machine()
    runs: dict[str, list[dict]] = {"per_task_env": [], "inherited_env": []}
    for rep in range(args.repeats):
        ways = ["per_task_env", "inherited_env"] if rep % 2 == 0 else ["inherited_env", "per_task_env"]
        for way in ways:
            runs[way].append(one_study(way == "per_task_env", args.cells, args.workers))
            print(f"repeat {rep} {way}: {runs[way][-1]}", flush=True)
    summary = {way: {k: statistics.median(r[k] for r in rs) for k in ("ray_init_s", "first_row_s", "first_row_after_init_s", "last_row_s")}
               for way, rs in runs.items()}
    for k in ("first_row_s", "first_row_after_init_s"):
        summary[f"{k[:-2]}_ratio_reference_over_default"] = summary["per_task_env"][k] / summary["inherited_env"][k]
    save("study_ray_latency", {"benchmark": "study_ray_latency", "machine": info,
                                 "parameters": {"repeats": args.repeats, "cells": args.cells,
                                                "workers": args.workers, "timing": "wall"},
                                 "runs": runs, "median": summary}, args.out)


if __name__ == "__main__":
    main()
