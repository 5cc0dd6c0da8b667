"""The one mechanism for telling the user what a command is doing: progress bars, warnings, a summary.

Everything here writes to **stderr**; stdout carries only what a command was asked to produce (a
score table, ``score --json``, a Markdown table), so ``decentral score --json ... > s.json`` stays
valid JSON and no feedback ever ends up in an output file.

- :func:`progress` opens a `tqdm <https://tqdm.github.io>`_ bar (counts, rate, ETA, and a postfix
  for e.g. ``rounds``/``messages``/``failed``). It is shown only when stderr is a terminal
  (``DECENTRAL_PROGRESS=always`` forces it, e.g. into a log file; ``never`` hides it) and never in
  quiet mode (``decentral -q``). A hidden bar costs nothing: every method is a no-op.
- :func:`summary` prints the one line that closes a command (``decentral localize: 240 steps, ...``);
  quiet mode silences it.
- :func:`warn` prints ``decentral CMD: warning: ...``; warnings are shown even in quiet mode, since
  they say that a result is not what was asked for (e.g. a consensus that did not converge).

The library (``decentral/``) never prints: long-running library functions take an optional
``progress(done, total, **info)`` callback, and a :class:`Progress` is such a callable.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
from dataclasses import dataclass
from typing import Iterable, Iterator, Mapping, TypeVar

from tqdm import tqdm

from sims.runners.run_status import EXIT_DEGRADED, cpu_hint, status_warning

__all__ = ["Progress", "configure", "configured", "is_quiet", "progress", "track", "summary", "warn", "add_strict",
           "report_status"]

T = TypeVar("T")

#: environment variable overriding when bars are shown: ``auto`` (stderr is a terminal), ``always``, ``never``
PROGRESS_ENV = "DECENTRAL_PROGRESS"


@dataclass
class _State:
    quiet: bool = False
    command: str | None = None


_state = _State()


def configure(*, quiet: bool | None = None, command: str | None = None) -> None:
    """Set quiet mode and the command name used to prefix messages (``decentral CMD: ...``)."""
    if quiet is not None:
        _state.quiet = bool(quiet)
    if command is not None:
        _state.command = command


@contextlib.contextmanager
def configured(*, quiet: bool | None = None, command: str | None = None) -> Iterator[None]:
    """:func:`configure` for the duration of a ``with`` block (for in-process callers and tests)."""
    saved = _State(_state.quiet, _state.command)
    configure(quiet=quiet, command=command)
    try:
        yield
    finally:
        _state.quiet, _state.command = saved.quiet, saved.command


def is_quiet() -> bool:
    """True when the user asked for silence (``decentral -q``)."""
    return _state.quiet


def _bars_enabled() -> bool:
    if _state.quiet:
        return False
    mode = os.environ.get(PROGRESS_ENV, "auto").strip().lower()
    if mode in ("always", "1", "yes", "true"):
        return True
    if mode in ("never", "0", "no", "false"):
        return False
    isatty = getattr(sys.stderr, "isatty", None)
    return bool(isatty and isatty())


def _prefix() -> str:
    return f"decentral {_state.command}: " if _state.command else "decentral: "


class Progress:
    """A progress bar on stderr; also a library ``progress(done, total, **info)`` callback.

    Parameters
    ----------
    bar : tqdm
        The underlying bar (``disable=True`` when hidden: then every method does nothing).
    """

    def __init__(self, bar: tqdm) -> None:
        self._bar = bar
        self._info: dict[str, object] = {}
        self.failed = 0
        self._fields_shown = False

    def __call__(self, done: int, total: int | None = None, **info: object) -> None:
        """Set the absolute count ``done`` (of ``total`` when given) and the postfix fields ``info``
        (they replace the previous call's; a call without fields keeps them)."""
        if total is not None and total != self._bar.total:
            self._bar.total = total
        self._bar.update(done - self._bar.n)
        self._post(info)

    def advance(self, n: int = 1, **info: object) -> None:
        """Count ``n`` more items done; postfix fields ``info`` as for a call."""
        self._bar.update(n)
        self._post(info)

    def fail(self, n: int = 1) -> None:
        """Count ``n`` failed items (shown as ``failed=N`` in the postfix, kept across calls)."""
        self.failed += n
        self._post(self._info)

    def _post(self, info: dict) -> None:
        if info:
            self._info = dict(info)
        if info or self.failed:
            shown = {**self._info, "failed": self.failed} if self.failed else self._info
            # the first fields are shown at once (a run shorter than the refresh interval would never show them)
            self._bar.set_postfix(shown, refresh=not self._fields_shown)
            self._fields_shown = True


@contextlib.contextmanager
def progress(desc: str, total: int | None = None, unit: str = "step", *, leave: bool | None = None) -> Iterator[Progress]:
    """Open a progress bar for ``total`` units of work (``None``: unknown, no ETA).

    Parameters
    ----------
    desc : str
        What is being counted, shown left of the bar (e.g. ``"steps"``, ``"admm"``).
    total : int, optional
        Expected count; a library callback may set or correct it later.
    unit : str
        Name of one unit (``step``, ``frame``, ``cell``).
    leave : bool, optional
        Keep the finished bar. Default: erase it on a terminal (the summary line follows), keep its
        final state when bars are forced onto a non-terminal (a log file then ends with the counts).
    """
    if leave is None:
        isatty = getattr(sys.stderr, "isatty", None)
        leave = not (isatty and isatty())
    bar = tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, leave=leave, disable=not _bars_enabled(),
               dynamic_ncols=True, mininterval=0.2)
    try:
        yield Progress(bar)
    finally:
        bar.close()


def track(iterable: Iterable[T], desc: str, total: int | None = None, unit: str = "step") -> Iterator[T]:
    """Yield from ``iterable`` while advancing a :func:`progress` bar by one per item."""
    if total is None and hasattr(iterable, "__len__"):
        total = len(iterable)  # type: ignore[arg-type]
    with progress(desc, total, unit) as bar:
        for item in iterable:
            yield item
            bar.advance()


def summary(line: str) -> None:
    """Print the command's closing one-line summary on stderr (silenced by quiet mode)."""
    if not _state.quiet:
        tqdm.write(_prefix() + line, file=sys.stderr)


def warn(message: str) -> None:
    """Print a one-line warning on stderr (shown even in quiet mode)."""
    tqdm.write(_prefix() + "warning: " + message, file=sys.stderr)


# ------------------------------------------------------------- a run's status (sims.runners.run_status)
def add_strict(parser: argparse.ArgumentParser) -> None:
    """Add ``--strict`` to a command's parser (``agent``, ``launch``)."""
    parser.add_argument("--strict", action="store_true",
                        help=f"exit with status {EXIT_DEGRADED} when stats.status is not 'ok' (some step did not "
                             "converge, or never ran); the estimate is written either way")


def report_status(stats: Mapping, steps: int, strict: bool) -> int:
    """Warn on stderr (one line) when ``stats['status']`` is not ``ok``; return the exit status ``--strict`` asks
    for (:data:`EXIT_DEGRADED`, else 0)."""
    line = status_warning(stats["status"], stats.get("status_counts", {}), steps)
    if line is None:
        return 0
    hint = cpu_hint(stats.get("behind_ms"), stats.get("round_period", 0.0)) if stats.get("round_period") else None
    line += f"; {hint}" if hint else ""
    warn(line + (f" (exit status {EXIT_DEGRADED})" if strict else "; --strict makes this exit "
                          f"{EXIT_DEGRADED}"))
    return EXIT_DEGRADED if strict else 0
