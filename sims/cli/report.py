"""``decentral report``: ``DIR/report.html`` (figures embedded) and the PNGs, from ``DIR/study.sqlite`` alone."""

from __future__ import annotations

import argparse

from sims.cli import feedback

__all__ = ["HELP", "add_arguments", "run"]

HELP = "write DIR/report.html and its PNG figures from a study's DIR/study.sqlite"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("directory", metavar="DIR", help="study directory (holds study.sqlite)")


def run(args: argparse.Namespace) -> int:
    from sims.io.kinds import require_folder
    from sims.lab.study.report import write_report

    require_folder(args.directory, "study.sqlite")
    result = write_report(args.directory)
    feedback.summary(f"{result.rows} cells ({result.failed} failed), {len(result.figures)} figures -> {result.html}")
    return 0
