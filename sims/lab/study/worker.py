"""What runs inside an engine's worker process. Imports nothing numeric at module level.

BLAS thread pools must be sized before numpy is first imported in a process, and the many small
dense factorizations of a cell run 10-100x slower with several threads on a loaded machine (see
``sims.cli.main.BLAS_THREAD_VARS``). Every worker therefore runs with one BLAS thread:
:data:`PINNED_ENV` is put in the environment the worker processes are started with, and
:func:`pin_blas_threads` (the local pool's initializer) sets it again in the worker before any cell
imports numpy.

A worker dies with the process that started it: :func:`init_worker` asks Linux to SIGKILL it when
its parent dies (``PR_SET_PDEATHSIG``), so a study killed with SIGKILL, which cannot run any
handler, leaves no worker behind; the multiprocessing resource tracker then sees every end of its
pipe closed and exits too.
"""

from __future__ import annotations

import ctypes
import os
import signal
from typing import Any, Mapping

__all__ = ["PINNED_ENV", "pin_blas_threads", "die_with_parent", "init_worker", "work"]

_PR_SET_PDEATHSIG = 1

#: environment of every worker: one thread per BLAS / OpenMP pool
PINNED_ENV = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def pin_blas_threads() -> None:
    """Set :data:`PINNED_ENV` in this process (call before numpy is imported)."""
    os.environ.update(PINNED_ENV)


def die_with_parent(parent: int) -> None:
    """Have the kernel SIGKILL this process when its parent (pid ``parent``) dies (Linux; elsewhere a no-op).

    Checks the parent after asking, so a parent that died just before is caught too.
    """
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    except (OSError, AttributeError):
        return  # not Linux: the study's own handlers still stop its pool
    if os.getppid() != parent:
        os.kill(os.getpid(), signal.SIGKILL)


def init_worker(parent: int) -> None:
    """The local pool's initializer: die with the study process ``parent``, then pin BLAS threads."""
    die_with_parent(parent)
    pin_blas_threads()


def work(command: str, params: Mapping[str, Any], key: str, texts: Mapping[str, str] | None = None) -> dict[str, Any]:
    """Run one cell in this process and return its row (see :func:`sims.lab.study.cells.execute`).

    ``texts``: the contents of the cell's input files (a recorded log), shipped with the task.
    """
    from sims.lab.study.cells import execute

    return execute(command, params, key, texts)
