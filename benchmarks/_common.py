"""Shared bits of the benchmark programs: single-core pinning, the argument parser, machine description, output.

Every benchmark builds its parser with :func:`parser` (its module docstring as the description, and
``--out DIR``) and parses the arguments before it runs anything, so ``--help`` only prints. Results
go to ``--out`` (default ``out/benchmarks``, git-ignored); the committed results in
``benchmarks/results`` are replaced only when a run is pointed there explicitly
(``--out benchmarks/results``).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one core, before numpy is imported

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from importlib import metadata  # noqa: E402
from pathlib import Path  # noqa: E402

from sims.io.atomic import write_atomic  # noqa: E402

#: the committed results (the README's figures and tables); written only when ``--out`` names it
RESULTS = Path(__file__).resolve().parent / "results"
#: where benchmark runs write by default (relative to the working directory; ``out/`` is git-ignored)
DEFAULT_OUT = Path("out") / "benchmarks"

__all__ = ["RESULTS", "DEFAULT_OUT", "parser", "output", "machine", "median_seconds", "save", "save_figure", "timed"]


def parser(doc: str) -> argparse.ArgumentParser:
    """The argument parser of a benchmark: ``doc`` (its module docstring) as help text, and ``--out DIR``."""
    ap = argparse.ArgumentParser(description=doc.strip(), formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT, metavar="DIR",
                    help=f"folder for the JSON results and figures (default {DEFAULT_OUT}, created if needed); "
                         "the committed results are replaced only with --out benchmarks/results")
    return ap


def output(out: Path, name: str, suffix: str = ".json") -> Path:
    """``out/<name><suffix>``, creating ``out``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    return out / f"{name}{suffix}"


def machine() -> dict:
    """Machine, versions and load at the time of the run."""
    versions = {}
    for pkg in ("numpy", "scipy", "cvxpy", "clarabel", "networkx", "opencv-python-headless", "pettingzoo",
                "pupil-apriltags"):
        try:
            versions[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            versions[pkg] = None
    return {
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "cpus": os.cpu_count(),
        "threads": os.environ.get("OMP_NUM_THREADS"),
        "loadavg_start": list(os.getloadavg()),
        "versions": versions,
        "date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }


def median_seconds(fn, reps: int, warmup: int) -> float:
    """Median wall time (s) of ``reps`` calls of ``fn()`` after ``warmup`` untimed calls."""
    import numpy as np

    for _ in range(warmup):
        fn()
    out = np.empty(reps)
    for i in range(reps):
        t0 = time.perf_counter()
        fn()
        out[i] = time.perf_counter() - t0
    return float(np.median(out))


def timed(fn, *args, **kwargs):
    """(result, seconds) of one call."""
    start = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - start


def save_figure(fig, path: Path, dpi: int = 110) -> None:
    """Write a matplotlib figure as PNG to ``path`` atomically and close it (like :func:`save`, an
    interrupted run leaves the previous plot, never half a file)."""
    import matplotlib.pyplot as plt

    write_atomic(path, lambda fh: fig.savefig(fh, format="png", dpi=dpi), binary=True)
    plt.close(fig)


def save(name: str, payload: dict, out: Path) -> Path:
    """Write ``payload`` to ``out/<name>.json`` (with the end-of-run load) and print it."""
    payload.setdefault("machine", machine())
    payload["machine"]["loadavg_end"] = list(os.getloadavg())
    path = output(out, name)
    text = json.dumps(payload, indent=1) + "\n"
    write_atomic(path, lambda fh: fh.write(text))  # an interrupted run never leaves half a result
    print(text, end="")
    return path
