"""``decentral build-log``: a rig file and the data it names (TUM/CSV odometry, detections, frames,
videos, ROS 1/2 bags) in, a ``decentral.log/1`` out. The rig format is in :mod:`sims.io.rig` and
``docs/rig.md``; the time association in :mod:`sims.runners.build_log`."""

from __future__ import annotations

import argparse

from sims.cli import feedback

__all__ = ["HELP", "add_arguments", "run"]

HELP = "build a decentral.log/1 from a rig file (TOML) and the robots' recorded data it names"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("rig", metavar="RIG.toml", help="rig file (decentral.rig/1): assemblies, cameras, data sources")
    parser.add_argument("-o", "--output", required=True, metavar="LOG.json", help="observation log to write")
    parser.add_argument("--report", metavar="REPORT.json",
                        help="also write what was matched and what was not (frame and step times) as JSON")


def run(args: argparse.Namespace) -> int:
    from decentral.errors import InputError
    from sims.runners.build_log import build_log
    from sims.io.atomic import write_json_atomic
    from sims.io.log_json import write_log
    from sims.io.paths import check_output
    from sims.io.rig import read_rig

    check_output(args.output, [args.rig])  # fail before the work, not half-way through the writes
    if args.report is not None:
        check_output(args.report, [args.rig, args.output], field="--report")
    rig = read_rig(args.rig)
    try:
        log, report = build_log(rig)
    except InputError as err:
        raise err.located(args.rig) from None
    write_log(args.output, log)
    if args.report:
        write_json_atomic(args.report, report.to_dict())
    feedback.summary(f"{report.summary()} -> {args.output}")
    return 0
