"""Shared bits of the benchmark programs: single-core pinning, machine description, JSON output."""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one core, before numpy is imported

import json  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from importlib import metadata  # noqa: E402
from pathlib import Path  # noqa: E402

from sims.io.atomic import write_atomic  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"

__all__ = ["RESULTS", "machine", "save", "save_figure", "timed"]


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


def save(name: str, payload: dict, directory: Path | None = None) -> Path:
    """Write ``payload`` to ``<directory>/<name>.json`` (default ``benchmarks/results``; with the
    end-of-run load) and print it."""
    payload.setdefault("machine", machine())
    payload["machine"]["loadavg_end"] = list(os.getloadavg())
    directory = RESULTS if directory is None else Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / f"{name}.json"
    text = json.dumps(payload, indent=1) + "\n"
    write_atomic(path, lambda fh: fh.write(text))  # an interrupted run never leaves half a result
    print(text, end="")
    return path
