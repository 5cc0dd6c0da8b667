"""The ``--strict`` option of the decentralized commands and the warning line of a run that is not ``ok``.

``localize --mode admm``, ``agent`` and ``launch`` write their estimate whatever happened, with
``stats.status`` (:mod:`sims.run_status`). When it is not ``ok`` they print one warning line on
stderr naming how many steps were provisional or unplaced and why; with ``--strict`` they also exit
with :data:`sims.run_status.EXIT_DEGRADED` (4), so that a script can tell a run whose every step
converged from one that only produced an answer.
"""

from __future__ import annotations

import argparse
from typing import Mapping

from sims.cli import feedback
from sims.run_status import EXIT_DEGRADED, status_warning

__all__ = ["EXIT_DEGRADED", "add_strict", "report_status"]


def add_strict(parser: argparse.ArgumentParser) -> None:
    """Add ``--strict`` to a command's parser."""
    parser.add_argument("--strict", action="store_true",
                        help=f"exit with status {EXIT_DEGRADED} when stats.status is not 'ok' (some step did not "
                             "converge, or never ran); the estimate is written either way")


def report_status(stats: Mapping, steps: int, strict: bool) -> int:
    """Warn (one line) when ``stats['status']`` is not ``ok``; return the exit status ``--strict`` asks for."""
    line = status_warning(stats["status"], stats.get("status_counts", {}), steps)
    if line is None:
        return 0
    feedback.warn(line + (f" (exit status {EXIT_DEGRADED})" if strict else "; --strict makes this exit "
                          f"{EXIT_DEGRADED}"))
    return EXIT_DEGRADED if strict else 0
