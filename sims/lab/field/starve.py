"""CPU starvation for the field harness: busy processes on the same cores as the agents.

:class:`Busy` starts ``per_core * cores`` processes that spin (at the agents' own priority unless
``nice`` says otherwise) and kills them when its ``with`` block ends.
"""

from __future__ import annotations

import os
import subprocess
import sys

__all__ = ["Busy"]

_SPIN = "while True:\n    pass\n"


class Busy:
    """``per_core`` spinning processes per CPU core this process may run on (a context manager)."""

    def __init__(self, per_core: int = 2, nice: int = 0):
        self.per_core, self.nice = int(per_core), int(nice)
        self.procs: list[subprocess.Popen] = []

    def __enter__(self) -> "Busy":
        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
        for _ in range(self.per_core * cores):
            self.procs.append(subprocess.Popen([sys.executable, "-c", _SPIN],
                                               preexec_fn=(lambda: os.nice(self.nice)) if self.nice else None))
        return self

    def __exit__(self, *exc) -> None:
        for proc in self.procs:
            proc.kill()
        for proc in self.procs:
            proc.wait()
        self.procs.clear()
