"""Running the CLI on hostile input, in-process or as a memory-capped subprocess, and what to check.

Every refusal must: exit 2, print exactly one stderr line naming the offending file (or option),
write nothing, and stay within 10 s and 1 GB.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import resource
import subprocess
import sys
import time
import tracemalloc
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sims.cli.main import main

__all__ = ["Outcome", "run_in_process", "run_subprocess", "assert_refused", "write_json_text", "write_npz",
           "MEMORY_CAP", "TIME_CAP"]

MEMORY_CAP = 1 << 30  # bytes
TIME_CAP = 10.0  # seconds


@dataclass
class Outcome:
    """What one CLI run did: exit status, stderr lines, files it created, wall time and peak memory."""

    status: int
    stderr: str
    created: set
    seconds: float
    peak_bytes: int

    @property
    def lines(self) -> list[str]:
        return self.stderr.splitlines()


def _files(root: Path) -> set:
    return {p.relative_to(root) for p in root.rglob("*")}


def run_in_process(argv: list[str], workdir: Path, *, trace_memory: bool = True) -> Outcome:
    """Call ``sims.cli.main.main(argv)`` with stdout/stderr captured (Python-level output only)."""
    before = _files(workdir)
    err, out = io.StringIO(), io.StringIO()
    if trace_memory:
        tracemalloc.start()
    t0 = time.perf_counter()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
            try:
                status = main([str(a) for a in argv])
            except SystemExit as done:  # argparse usage errors
                status = done.code
        seconds = time.perf_counter() - t0
        peak = tracemalloc.get_traced_memory()[1] if trace_memory else 0
    finally:
        if trace_memory:
            tracemalloc.stop()
    return Outcome(int(status or 0), err.getvalue(), _files(workdir) - before, seconds, peak)


def _cap_memory() -> None:  # runs in the child before exec
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_CAP, MEMORY_CAP))


def run_subprocess(argv: list[str], workdir: Path, env: dict | None = None) -> Outcome:
    """Run ``python -m sims.cli.main argv`` with a 1 GB address-space cap and a 10 s timeout (fd-level stderr)."""
    before = _files(workdir)
    full_env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", **(env or {})}
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "sims.cli.main", *map(str, argv)], cwd=workdir, env=full_env,
                          capture_output=True, text=True, timeout=TIME_CAP + 20, preexec_fn=_cap_memory)
    seconds = time.perf_counter() - t0
    return Outcome(proc.returncode, proc.stderr, _files(workdir) - before, seconds, 0)


def assert_refused(outcome: Outcome, names: str, *, startup: float = 0.0) -> None:
    """Exit 2, one stderr line naming ``names``, nothing written, within the time and memory caps."""
    assert outcome.status == 2, (outcome.status, outcome.stderr)
    assert len(outcome.lines) == 1, outcome.stderr
    line = outcome.lines[0]
    assert names in line, line
    assert "Traceback" not in outcome.stderr and "internal error" not in line, line
    assert not outcome.created, outcome.created
    assert outcome.seconds < TIME_CAP + startup, outcome.seconds
    assert outcome.peak_bytes < MEMORY_CAP, outcome.peak_bytes


def write_json_text(path: Path, doc_or_text) -> Path:
    """Write a document (or raw text) as a JSON file."""
    path.write_text(doc_or_text if isinstance(doc_or_text, str) else json.dumps(doc_or_text), encoding="utf-8")
    return path


def write_npz(path: Path, **arrays) -> Path:
    """Write arrays as an uncompressed ``.npz`` file."""
    with open(path, "wb") as fh:
        np.savez(fh, **{k: np.asarray(v) for k, v in arrays.items()})
    return path
