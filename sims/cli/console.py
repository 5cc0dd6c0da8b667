"""``decentral console``: a live web view of the swarm under an operator, of running agents, or a replay."""

from __future__ import annotations

import argparse
import sys

from decentral.errors import DecentralError, InputError
from sims.cli import feedback

__all__ = ["HELP", "add_arguments", "run"]

HELP = "serve a local web page: drive Kanovsky's swarm, follow running agents' streams, or replay a run"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    src = parser.add_mutually_exclusive_group(required=True)
    src.add_argument("--swarm", action="store_true", help="Kanovsky's camera swarm under the operator's control")
    src.add_argument("--streams", nargs="+", metavar="PATH",
                     help="agents' --stream files, or a `decentral launch --workdir` folder, followed as they grow")
    src.add_argument("--replay", nargs=2, metavar=("LOG.json", "EST.json"), help="a finished log and its estimate")
    parser.add_argument("--truth", metavar="TRUTH.json", help="ground truth (decentral.truth/1) for --streams/--replay")
    parser.add_argument("--reference", default=None, help="reference assembly of the streams (default: the truth's)")
    sw = parser.add_argument_group("swarm")
    sw.add_argument("--robots", type=int, default=6, help="number of robots (default: 6)")
    sw.add_argument("--arena", type=float, default=None, help="side of the square arena [m] (default: 5, grown "
                                                             "with the number of robots)")
    sw.add_argument("--dt", type=float, default=0.1, help="step [s] (default: 0.1: ten steps per second)")
    sw.add_argument("--display-hz", type=float, default=20.0,
                    help="most top-view updates pushed to the page per second (default: 20; every step is shown "
                         "while the swarm steps slower)")
    sw.add_argument("--seed", type=int, default=0, help="seed (default: 0)")
    sw.add_argument("--loss", type=float, default=0.0, help="probability that a radio copy is lost (default: 0)")
    sw.add_argument("--max-angle", type=float, default=50.0, help="camera half field of view [deg] (default: 50)")
    sw.add_argument("--max-distance", type=float, default=3.5, help="camera range [m] (default: 3.5)")
    sw.add_argument("--auto", action="store_true",
                    help="every robot takes pictures, reports and reads every step, and wanders")
    sw.add_argument("--steps", type=int, default=200, help="steps of a --mcap export of the swarm (default: 200)")
    parser.add_argument("--mcap", metavar="OUT.mcap",
                        help="write the source's streams as an MCAP file (Foxglove, Rerun) and exit without serving")
    parser.add_argument("--host", default="127.0.0.1",
                        help="address to listen on (default: 127.0.0.1, this machine only)")
    parser.add_argument("--port", type=int, default=8765, help="port (default: 8765)")


def swarm_config(args: argparse.Namespace):
    """The :class:`SwarmConfig` the swarm options describe."""
    import math

    from protocols.network import LinkConfig
    from sims.simulation.swarm import SwarmConfig

    if not 0.0 <= args.loss < 1.0:
        raise InputError(f"must be in [0, 1), got {args.loss}", field="--loss")
    arena = args.arena if args.arena is not None else max(5.0, 5.0 * math.sqrt(args.robots / 6.0))
    return SwarmConfig(n_robots=args.robots, arena=arena, dt=args.dt, max_angle_deg=args.max_angle,
                       max_distance=args.max_distance,
                       link=LinkConfig(drop=args.loss, latency=0.005, jitter=min(0.01, args.dt * 0.1)))


def _check_host(host: str) -> None:
    import ipaddress

    try:
        loopback = ipaddress.ip_address(host).is_loopback
    except ValueError:
        loopback = host == "localhost"
    if not loopback:
        feedback.warn(f"listening on {host}: anyone who can reach this address can drive the robots "
                      "(there is no login); use the default 127.0.0.1 unless you mean it")


def run(args: argparse.Namespace) -> int:
    if not 0 < args.port < 65536:
        raise InputError(f"must be in 1..65535, got {args.port}", field="--port")
    truth = None
    if args.truth:
        from sims.simulation.world.truth import read_truth

        truth = read_truth(args.truth)
    if args.swarm:
        from sims.console.operator import OperatorSwarm

        if not args.display_hz > 0:
            raise InputError(f"must be positive, got {args.display_hz}", field="--display-hz")

        op = OperatorSwarm(swarm_config(args), args.seed, auto=args.auto)
        if args.mcap:
            from sims.console.mcap_export import write_swarm_mcap

            n = write_swarm_mcap(args.mcap, op, args.steps)
            feedback.summary(f"{args.steps} steps of {args.robots} robots, {n} messages -> {args.mcap}")
            return 0
        source = {"kind": "swarm"}
    elif args.replay:
        from sims.console.views import Replay
        from sims.io.log_json import read_estimate, read_log

        replay = Replay(read_log(args.replay[0]), read_estimate(args.replay[1]), truth)
        if args.mcap:
            from sims.console.mcap_export import write_replay_mcap

            n = write_replay_mcap(args.mcap, replay)
            feedback.summary(f"{len(replay)} steps, {n} messages -> {args.mcap}")
            return 0
        source = {"kind": "replay", "replay": replay}
    else:
        from pathlib import Path

        from sims.console.streams import StreamFollower

        missing = [p for p in args.streams if not Path(p).exists()]
        if missing and args.mcap:
            raise InputError("no such file or folder", source=missing[0], field="--streams")
        follower = StreamFollower(args.streams)
        reference = args.reference or (truth.reference if truth is not None else None)
        if args.mcap:
            from sims.console.mcap_export import write_streams_mcap

            follower.poll()
            n = write_streams_mcap(args.mcap, follower)
            feedback.summary(f"{len(follower.agents)} agents, {n} messages -> {args.mcap}")
            return 0
        source = {"kind": "launch", "follower": follower, "truth": truth, "reference": reference}
    try:
        from sims.console.app import SwarmRunner, serve
    except ImportError as err:
        raise DecentralError(f"the console needs its optional libraries ({err.name} is missing): "
                             "pip install 'decentral[console]'") from None
    if args.swarm:
        source["runner"] = SwarmRunner(op, display_hz=args.display_hz)
    _check_host(args.host)
    print(f"decentral console: http://{args.host}:{args.port}/ (Ctrl-C to stop)", file=sys.stderr, flush=True)
    serve(source, host=args.host, port=args.port)
    return 0
