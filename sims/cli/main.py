"""Entry point of the ``decentral`` console script.

Each subcommand lives in its own module under :mod:`sims.cli` and exposes ``HELP`` (one line),
``add_arguments(parser)`` and ``run(args) -> int``. The registry below is explicit (a test checks it
against the files on disk). Every failure becomes one line on stderr and exit status 2
(:func:`_run_mapped`); nothing else is printed, and no traceback.

``decentral --version`` prints the installed version; ``-q``/``--quiet`` (before or after the
subcommand) silences progress bars and the closing summary line (:mod:`sims.cli.feedback`).
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from importlib.metadata import PackageNotFoundError, version

from decentral.errors import DecentralError
from sims.cli import feedback

__all__ = ["COMMANDS", "build_parser", "main"]

#: subcommand name -> module implementing it (imported lazily, so ``decentral --help`` stays fast)
COMMANDS: dict[str, str] = {
    "demo": "sims.cli.demo",
    "localize": "sims.cli.localize",
    "score": "sims.cli.score",
    "simulate": "sims.cli.simulate",
    "perceive": "sims.cli.perceive",
    "train-detector": "sims.cli.train_detector",
    "experiment": "sims.cli.experiment",
    "make-ensemble": "sims.cli.make_ensemble",
    "ensemble": "sims.cli.ensemble",
    "export": "sims.cli.export",
    "build-log": "sims.cli.build_log",
    "keys": "sims.cli.keys",
    "parts": "sims.cli.parts",
    "agent": "sims.cli.agent",
    "launch": "sims.cli.launch",
    "study": "sims.cli.study",
    "report": "sims.cli.report",
}

EXIT_BAD_INPUT = 2
#: a decentralized run finished but placed nothing (e.g. every message lost); its output is still written
EXIT_NO_RESULT = 3

QUIET_HELP = "no progress bars and no summary line (warnings and errors still go to stderr)"


def package_version() -> str:
    """The installed ``decentral`` version (``unknown`` when run from a source tree that is not installed)."""
    try:
        return version("decentral")
    except PackageNotFoundError:
        return "unknown"


class _OneLineParser(argparse.ArgumentParser):
    """A parser whose usage errors are one stderr line (and exit status 2) like every other failure."""

    def error(self, message: str):
        self.exit(EXIT_BAD_INPUT, _error_line(self.prog.removeprefix("decentral").strip(), f"error: {message}")
                  + f" (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    """Return the top-level parser with every registered subcommand attached."""
    parser = _OneLineParser(
        prog="decentral",
        description="Decentralized multi-observer relative localization for modular robots.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {package_version()}")
    parser.add_argument("-q", "--quiet", action="store_true", help=QUIET_HELP)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, module_name in COMMANDS.items():
        module = importlib.import_module(module_name)
        cmd = sub.add_parser(name, help=module.HELP, description=module.HELP)
        module.add_arguments(cmd)
        # SUPPRESS: absent after the subcommand, the top-level value stands
        cmd.add_argument("-q", "--quiet", action="store_true", default=argparse.SUPPRESS, help=QUIET_HELP)
        cmd.set_defaults(_run=module.run)
    return parser


#: BLAS thread pools spin on the many small dense factorizations here: one thread was 10-100x faster
#: on a loaded 2-core machine (measured: a 6-assembly log took 12 s multi-threaded, 0.3 s single)
BLAS_THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def main(argv: list[str] | None = None) -> int:
    """Parse ``argv``, run the subcommand and return its exit status (also used as the script)."""
    for var in BLAS_THREAD_VARS:  # before numpy is first imported (by build_parser); a user's setting wins
        os.environ.setdefault(var, "1")
    parser = build_parser()
    args = parser.parse_args(argv)
    feedback.configure(quiet=args.quiet, command=args.command)
    return _run_mapped(args)


#: longest error line printed (a hostile file can put megabytes into a value we quote)
MAX_ERROR_CHARS = 400


def _error_line(command: str, text: str) -> str:
    """One line on stderr: newlines folded, overlong messages cut."""
    text = " ".join(str(text).split())
    if len(text) > MAX_ERROR_CHARS:
        text = text[: MAX_ERROR_CHARS - 3] + "..."
    return f"decentral {command}: {text}" if command else f"decentral: {text}"


class _Terminated(KeyboardInterrupt):
    """SIGTERM, raised like Ctrl-C so that every ``finally`` (temporary files) runs."""


def _on_sigterm(signum, frame):  # noqa: ARG001 - the signal module's signature
    raise _Terminated


def _run_mapped(args: argparse.Namespace) -> int:
    """Run the subcommand; every failure becomes exactly one stderr line and exit status 2.

    Known errors (:class:`DecentralError`) print their message (file and field); anything else is
    a bug or an exhausted resource and says so in one line (``DECENTRAL_DEBUG=1`` re-raises it for
    a traceback). Warnings (numpy's RuntimeWarnings among them) are captured, never printed, unless
    debugging. SIGTERM is handled like SIGINT so temporary files are removed on the way out.
    """
    import signal
    import warnings

    debug = bool(os.environ.get("DECENTRAL_DEBUG"))
    try:
        previous = signal.signal(signal.SIGTERM, _on_sigterm)
    except ValueError:  # not the main thread: leave signals alone
        previous = None
    try:
        with warnings.catch_warnings():
            if not debug:
                warnings.simplefilter("ignore")
            status = args._run(args)
    except DecentralError as err:
        print(_error_line(args.command, f"error: {err}"), file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt as err:
        print(_error_line(args.command, "terminated" if isinstance(err, _Terminated) else "interrupted"),
              file=sys.stderr)
        return 143 if isinstance(err, _Terminated) else 130
    except MemoryError:
        print(_error_line(args.command, "error: out of memory (an input larger than this machine can hold; "
                                        "see the limits in the README)"), file=sys.stderr)
        return EXIT_BAD_INPUT
    except Exception as err:  # a bug, not a known error: still one line and the bad-input status
        if debug:
            raise
        print(_error_line(args.command, f"error: internal error: {type(err).__name__}: {err} "
                                        "(set DECENTRAL_DEBUG=1 for a traceback)"), file=sys.stderr)
        return EXIT_BAD_INPUT
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
    return int(status or 0)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
