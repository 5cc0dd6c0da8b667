"""What runs inside an engine's worker process. Imports nothing numeric at module level.

BLAS thread pools must be sized before numpy is first imported in a process, and the many small
dense factorizations of a cell run 10-100x slower with several threads on a loaded machine (see
``sims.cli.main.BLAS_THREAD_VARS``). Every worker therefore runs with one BLAS thread:
:data:`PINNED_ENV` is put in the environment the worker processes are started with, and
:func:`pin_blas_threads` (the local pool's initializer) sets it again in the worker before any cell
imports numpy.
"""

from __future__ import annotations

import os
from typing import Any, Mapping

__all__ = ["PINNED_ENV", "pin_blas_threads", "work"]

#: environment of every worker: one thread per BLAS / OpenMP pool
PINNED_ENV = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def pin_blas_threads() -> None:
    """Set :data:`PINNED_ENV` in this process (call before numpy is imported)."""
    os.environ.update(PINNED_ENV)


def work(command: str, params: Mapping[str, Any], key: str, texts: Mapping[str, str] | None = None) -> dict[str, Any]:
    """Run one cell in this process and return its row (see :func:`sims.study.cells.execute`).

    ``texts``: the contents of the cell's input files (a recorded log), shipped with the task.
    """
    from sims.study.cells import execute

    return execute(command, params, key, texts)
