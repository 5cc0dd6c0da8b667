"""Entry point of the ``decentral`` console script.

Each subcommand lives in its own module under :mod:`sims.cli` and exposes ``HELP`` (one line),
``add_arguments(parser)`` and ``run(args) -> int``. The registry below is explicit (a test checks it
against the files on disk). Known errors (:class:`decentral.DecentralError`) become one line on
stderr and exit status 2; nothing else is printed, and no traceback.

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
    "experiment": "sims.cli.experiment",
    "make-ensemble": "sims.cli.make_ensemble",
    "ensemble": "sims.cli.ensemble",
    "study": "sims.cli.study",
    "report": "sims.cli.report",
}

EXIT_BAD_INPUT = 2
EXIT_INTERNAL = 1
#: a decentralized run finished but placed nothing (e.g. every message lost); its output is still written
EXIT_NO_RESULT = 3

QUIET_HELP = "no progress bars and no summary line (warnings and errors still go to stderr)"


def package_version() -> str:
    """The installed ``decentral`` version (``unknown`` when run from a source tree that is not installed)."""
    try:
        return version("decentral")
    except PackageNotFoundError:
        return "unknown"


def build_parser() -> argparse.ArgumentParser:
    """Return the top-level parser with every registered subcommand attached."""
    parser = argparse.ArgumentParser(
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
    try:
        status = args._run(args)
    except DecentralError as err:
        print(f"decentral {args.command}: error: {err}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print(f"decentral {args.command}: interrupted", file=sys.stderr)
        return 130
    except Exception as err:  # a bug, not bad input: say so in one line unless debugging
        if os.environ.get("DECENTRAL_DEBUG"):
            raise
        print(
            f"decentral {args.command}: internal error: {type(err).__name__}: {err} "
            "(set DECENTRAL_DEBUG=1 for a traceback)",
            file=sys.stderr,
        )
        return EXIT_INTERNAL
    return int(status or 0)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
