"""``decentral launch``: a whole log as one ``decentral agent`` process per assembly on loopback (docs/processes.md)."""

from __future__ import annotations

import argparse

from decentral.errors import InputError
from sims.cli import feedback

__all__ = ["HELP", "add_arguments", "run"]

HELP = "run a log as one agent process per assembly over authenticated loopback sockets"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("log", metavar="LOG.json", help="observation log (decentral.log/1)")
    parser.add_argument("-o", "--output", required=True, metavar="EST.json", help="the reference agent's estimate")
    parser.add_argument("--window", type=int, default=5, help="steps per sliding window K (default: 5)")
    parser.add_argument("--reference", default=None, help="reference assembly (default: the first listed)")
    parser.add_argument("--loss", type=float, default=0.0,
                        help="probability that a frame is dropped at the receiving side (default: 0)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the losses (default: 0)")
    parser.add_argument("--crash", action="append", default=[], metavar="NAME@STEP[+DOWN]",
                        help="SIGKILL NAME's process when the log reaches STEP and start a fresh one DOWN steps "
                             "later (repeatable; without +DOWN it stays down)")
    parser.add_argument("--timeout", type=float, default=None, metavar="SECONDS",
                        help="kill every process after this many seconds and write what was gathered")
    parser.add_argument("--rate", type=float, default=1.0,
                        help="log seconds per wall second (default: 1: the log's timestamps)")
    parser.add_argument("--round-period", type=float, default=0.01,
                        help="wall seconds per consensus round (default: 0.01)")
    parser.add_argument("--absent", action="append", default=[], metavar="NAME",
                        help="never start NAME's agent (a peer that never comes up; repeatable)")
    parser.add_argument("--transport", choices=("zmq", "udp"), default=None,
                        help="the agents' transport (default: decentral agent's, see its --help)")
    parser.add_argument("--aggregation", choices=("tree", "broadcast"), default="tree",
                        help="how a window's forms travel between the agents: the aggregation tree (default: fewest "
                             "bytes; broadcast while an agent runs late) or always broadcast (one trip, more bytes, "
                             "fewer lie tests; see decentral agent --help)")
    feedback.add_strict(parser)
    parser.add_argument("--workdir", default=None,
                        help="keep keys, peers file, parts and per-agent streams here (default: a temporary folder)")


def run(args: argparse.Namespace) -> int:
    from sims.io.log_json import read_log, write_estimate
    from sims.runners.launch import LaunchConfig, launch, parse_crash

    if args.window < 1:
        raise InputError(f"must be >= 1, got {args.window}", field="--window")
    if not 0.0 <= args.loss < 1.0:
        raise InputError(f"must be in [0, 1), got {args.loss}", field="--loss")
    if args.timeout is not None and not args.timeout > 0:
        raise InputError(f"must be > 0, got {args.timeout}", field="--timeout")
    if not args.rate > 0 or not args.round_period > 0:
        raise InputError("must be > 0", field="--rate/--round-period")
    crashes = tuple(parse_crash(c) for c in args.crash)
    log = read_log(args.log)
    config = LaunchConfig(window=args.window, reference=args.reference, loss=args.loss, seed=args.seed,
                          crashes=crashes, timeout=args.timeout, rate=args.rate, round_period=args.round_period,
                          absent=tuple(args.absent), transport=args.transport, aggregation=args.aggregation)
    result = launch(log, config, workdir=args.workdir)
    write_estimate(args.output, result.estimate)
    stats = result.estimate.stats
    if stats["missing"]:
        feedback.warn(f"the reference never heard from {', '.join(stats['missing'])}")
    for agent, line in stats.get("agent_errors", {}).items():
        feedback.warn(f"agent process {agent} failed: {line}")
    if result.timed_out:
        why = (f"timed out after {args.timeout:g} s" if args.timeout is not None else
               "agents still running 30 s after the last step was due (kept off the CPU?)")
        feedback.warn(f"{why}; wrote the steps gathered, stats.status {stats['status']}")
        return 1
    placed = sum(1 for step in result.estimate.steps if step.poses)
    feedback.summary(f"{len(result.estimate.steps)} steps ({placed} placing someone), {stats['processes']} processes, "
                     f"{stats['messages']['total']} frames, {stats['bytes']['total']} bytes, "
                     f"{sum(stats['rejected'].values())} refused, status {stats['status']} -> {args.output}")
    return feedback.report_status(stats, len(result.estimate.steps), args.strict)
