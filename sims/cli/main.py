"""Entry point of the ``decentral`` console script.

Each subcommand lives in its own module under :mod:`sims.cli` and exposes ``HELP`` (one line),
``add_arguments(parser)`` and ``run(args) -> int``. The registry below is explicit (a test checks it
against the files on disk). Every failure becomes one line on stderr and exit status 2
(:func:`_run_mapped`); nothing else is printed, and no traceback.

``decentral --version`` prints the installed version; ``-q``/``--quiet`` (before or after the
subcommand) silences progress bars and the closing summary line (:mod:`sims.cli.feedback`).

Start-up stays fast: a command module's top level imports only the standard library and light
project modules (numpy, scipy and OpenCV are imported in its ``run``), and only the command being
run attaches its arguments (:func:`build_parser`), so ``decentral --help``, ``--version`` and
``decentral COMMAND --help`` cost a fraction of a second (tests/sims/test_cli_startup.py).
Abbreviated options are refused (``allow_abbrev=False``); an unknown option names the command's
own ``--help`` and the closest valid option (:meth:`_OneLineParser.unknown`).
"""

from __future__ import annotations

import argparse
import difflib
import importlib
import os
import re
import shutil
import sys
import textwrap
from functools import partial
from importlib.metadata import PackageNotFoundError, version
from typing import Iterable

from decentral.errors import DecentralError
from sims.cli import feedback

__all__ = ["COMMANDS", "GROUPS", "build_parser", "main"]

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
    "console": "sims.cli.console",
}

#: ``decentral --help`` lists the commands by workflow: title -> (commands, one example line); a
#: registered command missing here is listed under "More commands"
GROUPS: dict[str, tuple[tuple[str, ...], str]] = {
    "Simulate and localize": (("demo", "simulate", "localize", "score", "experiment"),
                              "decentral simulate table1 -o run && decentral localize run/log.json -o run/est.json"),
    "Your robots' data": (("perceive", "train-detector", "build-log", "export"),
                          "decentral build-log rig.toml -o log.json && decentral export est.json -o tum --format tum"),
    "Ensembles": (("make-ensemble", "ensemble"),
                  "decentral make-ensemble triple -n 1000 -o obs.npz --truth truth.npz && "
                  "decentral ensemble obs.npz -o est.npz"),
    "Agents as processes": (("keys", "parts", "agent", "launch"),
                            "decentral launch run/log.json -o est.json --loss 0.1 --crash A1@20+5"),
    "Studies": (("study", "report"), "decentral study sweep.toml -o study && decentral report study"),
    "Watch it live": (("console",), "decentral console --swarm --robots 10   (then open http://127.0.0.1:8765/)"),
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
    """A parser whose usage errors are one stderr line (and exit status 2) like every other failure.

    Abbreviations are refused (``--wind 3`` is not ``--window 3``); an error names this parser's own
    ``--help`` and, for a mistyped option or choice, the closest valid one.
    """

    def __init__(self, *args, **kwargs) -> None:
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)

    def parse_known_args(self, args=None, namespace=None):
        self._given = list(sys.argv[1:] if args is None else args)  # for error(): what the user typed
        return super().parse_known_args(args, namespace)

    def error(self, message: str):
        if message.startswith("the following arguments are required"):
            # a missing option is often a misspelt one (`--out` for `--output`): say so in the same line
            strangers = [a for a in getattr(self, "_given", []) if a.startswith("-") and not a[1:2].isdigit()
                         and a.split("=", 1)[0] not in self._option_string_actions]
            message += f"; {self._unrecognized(strangers)}" if strangers else ""
        self.exit(EXIT_BAD_INPUT, _error_line(self.prog.removeprefix("decentral").strip(),
                                              f"error: {message}{_did_you_mean_choice(message)}")
                  + f" (see {self.prog} --help)\n")

    def unknown(self, extras: list[str]):
        """Refuse the arguments this parser does not know, suggesting the closest option it has."""
        self.error(self._unrecognized(extras))

    def _unrecognized(self, extras: list[str]) -> str:
        """``unrecognized option --windw (did you mean --window?)`` for the first unknown option of ``extras``."""
        options = [s for a in self._actions for s in a.option_strings if a.help != argparse.SUPPRESS]
        words = [e for e in extras if e.startswith("-")] or extras
        word = words[0].split("=", 1)[0]
        close = difflib.get_close_matches(word, options, n=1, cutoff=0.6) if word.startswith("-") else []
        hint = f" (did you mean {close[0]}?)" if close else ""
        kind = "option" if word.startswith("-") else "argument"
        more = [e for e in words[1:] if e.startswith("-")]
        others = f" (also unrecognized: {' '.join(more)})" if more else ""
        return f"unrecognized {kind} {word}{hint}{others}"


_INVALID_CHOICE = re.compile(r"invalid choice: '([^']*)' \(choose from (.*)\)$")


def _did_you_mean_choice(message: str) -> str:
    """`` (did you mean X?)`` for argparse's 'invalid choice' message when one choice is close."""
    match = _INVALID_CHOICE.search(message)
    if not match:
        return ""
    choices = re.findall(r"'([^']*)'", match.group(2))
    close = difflib.get_close_matches(match.group(1), choices, n=1, cutoff=0.6)
    return f" (did you mean {close[0]}?)" if close else ""


def _grouped_commands(helps: dict[str, str]) -> str:
    """The commands by workflow, each with its one-line help, and one example per workflow."""
    width = max(map(len, helps)) + 2
    columns = min(max(shutil.get_terminal_size().columns - 2, 60), 120)
    wrap = partial(textwrap.fill, width=columns, break_on_hyphens=False, break_long_words=False)
    listed: set[str] = set()
    lines: list[str] = []
    extra = tuple(name for name in helps if not any(name in names for names, _ in GROUPS.values()))
    for title, (names, example) in {**GROUPS, **({"More commands": (extra, "")} if extra else {})}.items():
        lines.append(f"{title}:")
        for name in names:
            if name in helps and name not in listed:
                listed.add(name)
                lines.append(wrap(f"  {name:<{width}}{helps[name]}", subsequent_indent=" " * (width + 2)))
        if example:
            lines.append(wrap(f"  e.g. {example}", subsequent_indent="       "))
        lines.append("")
    lines.append("Run 'decentral COMMAND --help' for a command's options and the files it reads and writes.")
    return "\n".join(lines)


def _command_in(argv: list[str]) -> str | None:
    """The subcommand named in ``argv`` (the first word that is not an option), or None."""
    for word in argv:
        if not word.startswith("-"):
            return word if word in COMMANDS else None
    return None


def build_parser(only: Iterable[str] | None = None) -> argparse.ArgumentParser:
    """Return the top-level parser with every registered subcommand attached.

    Parameters
    ----------
    only : iterable of str, optional
        Attach the options of these subcommands only (the others get their name and one-line help,
        enough for ``decentral --help``); default: every subcommand's options (for docs and tests).
    """
    only = None if only is None else set(only)
    modules = {name: importlib.import_module(module_name) for name, module_name in COMMANDS.items()}
    parser = _OneLineParser(
        prog="decentral",
        usage="decentral [-h] [--version] [-q] COMMAND ...",
        description="Decentralized multi-observer relative localization for modular robots.\n\n"
                    + _grouped_commands({name: module.HELP for name, module in modules.items()}),
        formatter_class=argparse.RawDescriptionHelpFormatter,  # the description lists the commands
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {package_version()}")
    parser.add_argument("-q", "--quiet", action="store_true", help=QUIET_HELP)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND", help=argparse.SUPPRESS)
    for name, module in modules.items():
        cmd = sub.add_parser(name, prog=f"decentral {name}", help=module.HELP, description=module.HELP)
        if only is None or name in only:
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
    for var in BLAS_THREAD_VARS:  # before numpy is first imported (by a command); a user's setting wins
        os.environ.setdefault(var, "1")
    argv = sys.argv[1:] if argv is None else list(argv)
    command = _command_in(argv)
    parser = build_parser([command] if command else [])
    args, extras = parser.parse_known_args(argv)
    if extras:  # refused by the subcommand's parser, so that the message names its --help and options
        next(a for a in parser._actions if a.dest == "command").choices[args.command].unknown(extras)
    feedback.configure(quiet=args.quiet, command=args.command)
    return _run_mapped(args)


#: longest error line printed (a hostile file can put megabytes into a value we quote)
MAX_ERROR_CHARS = 1000


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
