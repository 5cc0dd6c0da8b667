"""``decentral agent``: one assembly's agent as its own process over the real transport (docs/processes.md)."""

from __future__ import annotations

import argparse
import json
import math
import signal
import sys
import time

from decentral.errors import InputError
from sims.cli import feedback

__all__ = ["HELP", "add_arguments", "run"]

HELP = "run one assembly's agent on its part of a log, talking to its peers over authenticated sockets"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("name", metavar="NAME", help="this agent's assembly")
    parser.add_argument("--log", required=True, metavar="PART.json",
                        help="this assembly's part of the log (decentral.log/1 with its own data only)")
    parser.add_argument("--peers", required=True, metavar="PEERS.json",
                        help="every assembly's address and public key (decentral.peers/1)")
    parser.add_argument("--key", required=True, metavar="KEYFILE",
                        help="this agent's private key (decentral.key/1, mode 0600); '-' reads it as one line "
                             "from stdin, so that it never touches a disk")
    parser.add_argument("--allow-readable-key", action="store_true",
                        help="accept a key file that group or others may read, with a warning (default: refuse)")
    parser.add_argument("-o", "--output", metavar="EST.json",
                        help="write this agent's estimate (poses relative to itself) when it ends")
    parser.add_argument("--reference", default=None,
                        help="assembly that pins the gauge (default: the first listed); the same for every agent")
    parser.add_argument("--window", type=int, default=5, help="steps per sliding window K (default: 5)")
    parser.add_argument("--start", default=None, metavar="UNIX_TIME",
                        help="wall time (seconds since the Unix epoch) of the log's first step, the same for every "
                             "agent (default: now); '-' prints 'ready' once listening and reads it from stdin")
    parser.add_argument("--rate", type=float, default=1.0,
                        help="log seconds per wall second (default: 1: the log's timestamps; 4: four times faster)")
    parser.add_argument("--round-period", type=float, default=0.01,
                        help="wall seconds per consensus round (default: 0.01); the same for every agent")
    parser.add_argument("--linger", type=float, default=1.0,
                        help="seconds to keep answering peers after the last step (default: 1; at least one step "
                             "period, two if the last window went on in the background)")
    parser.add_argument("--loss", type=float, default=0.0,
                        help="drop each arriving frame with this probability (testing; default 0)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the receive-side losses (default: 0)")
    parser.add_argument("--clock-tolerance", type=float, default=5.0, metavar="SECONDS",
                        help="refuse frames sent more than this long before this agent started, or this far ahead of its "
                             "clock, so that frames of an earlier run are refused; peers' clocks must agree within "
                             "it (default: 5)")
    parser.add_argument("--transport", choices=("zmq", "udp"), default=DEFAULT_TRANSPORT,
                        help="udp: signed datagrams, a lost packet is a lost frame; zmq: ZeroMQ over TCP, a lost "
                             "packet stalls the frames behind it (default: %(default)s); the same for every agent")
    parser.add_argument("--aggregation", choices=("tree", "broadcast"), default="tree",
                        help="how a window's cost forms travel: up and down the aggregation tree (default: fewest "
                             "bytes, every lie test; an agent leaves it for broadcast while links are too slow for "
                             "it or its process runs late on a busy computer) or always broadcast to every agent "
                             "(one trip instead of one per tree level, up to about eight times the bytes, "
                             "member-wide lie tests only after the cold start); the same for every agent")
    parser.add_argument("--parity-group", type=int, default=4, metavar="N",
                        help="udp: one parity datagram per N datagrams of a frame, so that a frame survives one lost "
                             "datagram in each group (0: none; default: 4); the same for every agent")
    feedback.add_strict(parser)
    parser.add_argument("--stream", metavar="FILE",
                        help="append each finished step to FILE as one JSON line at once (survives a kill)")


#: the transport every agent uses unless told otherwise: under 20 % packet loss and 30 ms links a 4-ring over
#: UDP converged 8 of 8 steps (frame latency p90 74 ms), over ZeroMQ/TCP 5 of 8 (p90 864 ms) (docs/processes.md)
DEFAULT_TRANSPORT = "udp"


def open_transport(kind: str, name: str, key, peers: dict, seed: int, faults, clock_tolerance: float | None = None,
                   parity_group: int = 4):
    """The real transport ``kind`` (``zmq`` or ``udp``) for agent ``name`` over ``peers``, refusing frames
    beyond ``clock_tolerance`` seconds as stale (UDP: one parity datagram per ``parity_group``)."""
    import numpy as np

    if kind == "udp":
        from protocols.udp_transport import UdpTransport

        return UdpTransport({name: key}, peers, rng=np.random.default_rng(seed), faults=faults, max_age=clock_tolerance,
                            parity_group=parity_group)
    from protocols.zmq_transport import ZmqTransport

    return ZmqTransport({name: key}, peers, rng=np.random.default_rng(seed), faults=faults, max_age=clock_tolerance)


def _sigterm(signum, frame):
    raise SystemExit(128 + signum)


def run(args: argparse.Namespace) -> int:
    from protocols.network import LinkConfig
    from protocols.peers import key_file_exposure, load_peers, load_private_key, read_private_key_text
    from sims.runners.agent_run import Pace, _counts, process_agent_config, run_agent
    from sims.io.log_json import write_estimate
    from sims.runners.parts import read_part

    if args.window < 1:
        raise InputError(f"must be >= 1, got {args.window}", field="--window")
    if not 0.0 <= args.loss < 1.0:
        raise InputError(f"must be in [0, 1), got {args.loss}", field="--loss")
    if not 0 <= args.parity_group <= 64:
        raise InputError(f"must be 0 (no parity) to 64, got {args.parity_group}", field="--parity-group")
    if not (math.isfinite(args.clock_tolerance) and args.clock_tolerance > 0):
        raise InputError(f"must be a positive number of seconds, got {args.clock_tolerance}", field="--clock-tolerance")
    from protocols.peers import KEY_FORMAT, PEERS_FORMAT
    from sims.io.kinds import require_kind

    part = read_part(args.log, args.name)
    require_kind(args.peers, PEERS_FORMAT, field="--peers")
    if args.key != "-":  # a key on stdin (how launch hands it over) is read below
        require_kind(args.key, KEY_FORMAT, field="--key")
    peers = load_peers(args.peers)
    if args.key == "-":
        key_name, key = read_private_key_text(sys.stdin.readline(), "<stdin>")
    else:
        key_name, key = load_private_key(args.key, allow_readable=args.allow_readable_key)
        exposure = key_file_exposure(args.key)
        if exposure:
            feedback.warn(f"{args.key}: private key {exposure}")
    if key_name != args.name:
        raise InputError(f"is {key_name!r}'s key, not {args.name!r}'s", source=args.key, field="name")
    missing = [a for a in part.assemblies if a not in peers]
    if missing:
        raise InputError(f"no address for {missing[0]!r}", source=args.peers, field="peers")
    reference = args.reference or part.assemblies[0]
    if reference not in part.assemblies:
        raise InputError(f"no assembly {reference!r} in {args.log}", field="--reference")
    config = process_agent_config(part, args.name, reference, args.window, args.rate, args.round_period,
                                  args.aggregation)
    signal.signal(signal.SIGTERM, _sigterm)
    faults = LinkConfig(drop=args.loss)
    transport = open_transport(args.transport, args.name, key, {n: peers[n] for n in part.assemblies}, args.seed,
                               faults, clock_tolerance=args.clock_tolerance, parity_group=args.parity_group)
    stream = open(args.stream, "a", encoding="utf-8") if args.stream else None
    try:
        if args.start == "-":
            print("ready", flush=True)
            line = sys.stdin.readline()
            start = _start_time(line.strip(), "stdin")
        elif args.start is not None:
            start = _start_time(args.start, "--start")
        else:
            start = time.time()
        pace = Pace(start=start, rate=args.rate, round_period=args.round_period, linger=args.linger)
        result = run_agent(part, args.name, transport, config, pace, stream=stream,
                           wait=lambda seconds: transport.wait(seconds))
    finally:
        transport.close()  # counts what is still queued as unread
        if stream is not None:
            try:
                stream.write(json.dumps({"final": True, "counts": _counts(transport, args.name)}) + "\n")
            finally:
                stream.close()
    offsets = transport.clock_offsets(args.name)
    if args.output:
        write_estimate(args.output, result.estimate)
    for peer, (lo, hi) in sorted(offsets.items()):
        if peer != args.name and (lo > args.clock_tolerance or hi < -args.clock_tolerance):
            feedback.warn(f"{peer}'s frames arrived {lo:+.2f} to {hi:+.2f} s from this clock: beyond the "
                          f"{args.clock_tolerance:g} s tolerance, refused as stale (clocks or start times disagree)")
    if result.stats["skipped"]:
        feedback.warn(f"{args.name} started {result.stats['skipped']} steps late: steps 0-{result.stats['skipped'] - 1} "
                      "were over (give a START further ahead: docs/processes.md, start margin)")
    for adopted in result.stats["adopted_start"]:
        feedback.warn(f"{args.name}: its peers started at {adopted['peers']:.3f}, not at the START given "
                      f"({adopted['given']:.3f}): it follows their clock")
    clock = result.stats["clock"]
    if clock["skewed"]:
        offsets = ", ".join(f"{p} {clock['start_offsets'][p]:+.2f} s" for p in clock["skewed"])
        feedback.warn(f"start times disagree (peer's start before this agent's --start: {offsets}); "
                      + (f"followed the earliest, {clock['moved']:.2f} s earlier" if clock["moved"] else
                         "this agent's start was the earliest"))
    if result.stats["missing"]:
        feedback.warn(f"{args.name} never heard from {', '.join(result.stats['missing'])}")
    stats = result.stats
    feedback.summary(f"{args.name}: {len(result.steps)} steps, {sum(stats['converged_per_step'])} converged, "
                     f"{stats['messages']['total']} frames sent, {sum(stats['rejected'].values())} refused, "
                     f"status {stats['status']}")
    return feedback.report_status(stats, len(part.steps), args.strict)


def _start_time(text: str, where: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise InputError(f"not a time: {text!r}", field=where) from None
    if not math.isfinite(value):
        raise InputError(f"not a time: {text!r}", field=where)
    return value
