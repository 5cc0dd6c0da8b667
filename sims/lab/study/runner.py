"""Run a study: check every cell, open the store, run the cells that have no row, write each row.

Only this process writes the store, one committed transaction per finished cell, so a study killed
at any instant keeps every finished cell and the next run of the same command runs exactly the
cells that have no row (the cell's parameters are a UNIQUE key: never a duplicate).
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
import socket
import subprocess
import sys
import time
from dataclasses import dataclass
from datetime import datetime, timezone
from importlib import metadata
from pathlib import Path
from typing import Callable

from sims.lab.study.cells import Cell, check_cells, metrics_of
from sims.lab.study.spec import StudySpec
from sims.lab.study.store import open_store

__all__ = ["StudyResult", "run_study", "provenance"]

#: distributions whose versions go into the provenance of every invocation
PACKAGES = ("decentral", "numpy", "scipy", "cvxpy", "clarabel", "networkx", "pymetis", "opencv-python-headless",
            "matplotlib", "ray")


@dataclass(frozen=True)
class StudyResult:
    """What one run of a study did.

    Attributes
    ----------
    total : int
        Cells of the spec.
    skipped : int
        Cells that already had a row (not run again).
    ran : int
        Cells run now (their rows are written).
    failed : int
        Of those, the ones whose row says 'failed'.
    seconds : float
        Wall time of this run.
    path : Path
        The store.
    """

    total: int
    skipped: int
    ran: int
    failed: int
    seconds: float
    path: Path


def _git_revision() -> str | None:
    root = Path(__file__).resolve().parents[2]
    try:
        out = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=5)
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=5)
    except (OSError, subprocess.SubprocessError):
        return None
    if out.returncode != 0:
        return None
    return out.stdout.strip() + ("+modified" if dirty.stdout.strip() else "")


def _versions() -> dict[str, str]:
    out = {}
    for name in PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
    return out


def provenance(spec: StudySpec, engine: str, workers: int | None, address: str | None) -> dict:
    """The ``invocations`` row of a run starting now: code, machine, and the spec's text."""
    return {
        "started": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "engine": engine, "workers": workers, "address": address,
        "spec": spec.text, "spec_sha256": hashlib.sha256(spec.text.encode()).hexdigest(),
        "git_revision": _git_revision(), "python": sys.version.split()[0], "platform": platform.platform(),
        "host": socket.gethostname(), "packages": json.dumps(_versions()), "status": "running", "pid": os.getpid(),
    }


def _alive(pid: int) -> bool:
    """Whether process ``pid`` exists on this machine."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        return True
    return True


def run_study(spec: StudySpec, directory: str | Path, engine, *, retry_failed: bool = False,
              progress: Callable | None = None, on_failed: Callable[[Cell, dict], None] | None = None
              ) -> StudyResult:
    """Run the cells of ``spec`` that have no row in ``directory/study.sqlite``.

    Parameters
    ----------
    spec : StudySpec
    directory : str or Path
        Where the store lives (created if needed).
    engine : LocalEngine or RayEngine
        Where the cells run (:func:`sims.lab.study.engines.make_engine`).
    retry_failed : bool
        Delete the 'failed' rows first, so that those cells run again.
    progress : callable, optional
        ``progress(done, total, failed=...)`` after every finished cell (e.g. a
        :class:`sims.cli.feedback.Progress`).
    on_failed : callable, optional
        ``on_failed(cell, row)`` for every cell whose row says 'failed' (after the row is written).

    Raises
    ------
    InputError
        A key or value of the spec is refused, or the store holds another study; nothing has run.
    """
    cells = check_cells(spec)
    metrics = metrics_of(spec.command)
    store = open_store(directory, spec.name, spec.command, spec.keys, metrics, spec.text)
    start = time.perf_counter()
    try:
        store.close_vanished_invocations(socket.gethostname(), _alive)
        if retry_failed:
            store.delete_failed()
        done = store.done_keys()
        pending = [c for c in cells if c.key not in done]
        skipped = len(cells) - len(pending)
        workers = getattr(engine, "workers", None)
        invocation = store.begin_invocation({**provenance(spec, engine.name, workers, getattr(engine, "address", None)),
                                       "cells_total": len(cells)})
        counts = {"ran": 0, "failed": 0}
        if progress:
            progress(0, len(pending), failed=0)

        def on_result(cell: Cell, row: dict) -> None:
            store.add_run(cell.params, row, engine.name, invocation)
            counts["ran"] += 1
            counts["failed"] += row["status"] == "failed"
            if on_failed and row["status"] == "failed":
                on_failed(cell, row)
            if progress:
                progress(counts["ran"], len(pending), failed=counts["failed"])

        status = "interrupted"
        try:
            engine.run(pending, on_result)
            status = "finished"
        finally:
            store.end_invocation(invocation, finished=datetime.now(timezone.utc).isoformat(timespec="seconds"),
                              cells_run=counts["ran"], cells_failed=counts["failed"], status=status)
    finally:
        store.close()
    return StudyResult(len(cells), skipped, counts["ran"], counts["failed"], time.perf_counter() - start,
                       store.path)


def default_workers() -> int:
    """Worker processes when ``--workers`` is not given: the CPUs this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)
