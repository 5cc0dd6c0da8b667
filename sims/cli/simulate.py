"""``decentral simulate``: run a scenario and write its observation log, its ground truth and frames."""

from __future__ import annotations

import argparse
import json

from decentral.errors import InputError
from sims.cli import feedback

__all__ = ["HELP", "add_arguments", "run", "parse_params"]

HELP = "simulate a scenario: write OUTDIR/log.json (decentral.log/1), OUTDIR/truth.json and frames"


#: the names of sims.simulation.scenarios.SCENARIOS and sims.simulation.robot_data.ODOMETRY_FORMATS, listed here so that
#: ``--help`` does not import numpy (a test keeps them equal)
SCENARIO_NAMES = ("table1", "reconfig", "multi", "single_node", "ring64")
ODOMETRY_FORMATS = ("tum", "csv", "ros1", "ros2")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Attach the command's arguments to ``parser``."""
    parser.add_argument("scenario", metavar="SCENARIO", help="scenario name: " + ", ".join(SCENARIO_NAMES))
    parser.add_argument("-o", "--output", required=True, metavar="OUTDIR", help="output folder (created if needed)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    parser.add_argument("--steps", type=int, default=None, help="number of steps (default: the scenario's)")
    parser.add_argument("--no-noise", action="store_true", help="exact sensors: no noise, drop-outs or outliers")
    parser.add_argument("--frames", choices=("png", "video", "none"), default="none",
                        help="also render camera frames as PNG files or one video per camera (default: none)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", dest="params",
                        help="scenario parameter (JSON value), e.g. --set n_assemblies=8 --set pixel_sigma=1.0")
    parser.add_argument("--robot-data", metavar="DIR",
                        help="also write the run as a robot would record it: DIR/rig.toml for `decentral build-log`, "
                             "odometry trajectories and per-camera detections (or images with --robot-images)")
    parser.add_argument("--robot-odometry", choices=ODOMETRY_FORMATS, default="tum",
                        help="--robot-data odometry as TUM or CSV files, or nav_msgs/Odometry in a ROS 1 bag "
                             "(DIR/run.bag) or a ROS 2 bag (DIR/run) (default: tum)")
    parser.add_argument("--robot-images", action="store_true",
                        help="--robot-data with rendered camera images (PNG files, or sensor_msgs/Image in the bag) "
                             "for build-log to perceive, instead of detection files")


def parse_params(items: list[str]) -> dict:
    """Turn ``KEY=VALUE`` strings into a dict; values are JSON, or plain strings when not JSON."""
    params = {}
    for item in items:
        key, sep, raw = item.partition("=")
        if not sep or not key.strip():
            raise InputError(f"expected KEY=VALUE, got {item!r}", field="--set")
        try:
            value = json.loads(raw)
        except json.JSONDecodeError:
            value = raw
        params[key.strip()] = value
    return params


def run(args: argparse.Namespace) -> int:
    """Simulate, then write the log, the truth and (optionally) frames into ``args.output``."""
    from sims.simulation.scenarios import get_scenario, simulate
    from sims.simulation.scenarios.output import save_simulation

    params = parse_params(args.params)
    if args.steps is not None:
        params["steps"] = args.steps
    if args.no_noise:
        params["noise"] = False
    scenario = get_scenario(args.scenario, **params)
    sim = simulate(scenario, seed=args.seed)
    with feedback.progress("render", unit="frame") as bar:
        saved = save_simulation(sim, args.output, frames=args.frames, seed=args.seed, progress=bar)
    robot = ""
    if args.robot_data:
        from sims.simulation.robot_data import write_robot_data

        rig = write_robot_data(sim, args.robot_data, odometry=args.robot_odometry, images=args.robot_images,
                               seed=args.seed)
        robot = f"; robot data: {rig}"
    n_frames = len(saved.frames)
    n_det = sum(len(d) for step in sim.log.steps for d in step.detections.values())
    feedback.summary(
        f"{args.scenario}: {len(sim.log.steps)} steps, {len(sim.log.assemblies)} assemblies, "
        f"{len(sim.log.cameras)} cameras, {n_det} detections -> {saved.log}, {saved.truth}"
        + (f", {n_frames} frame files" if n_frames else "") + robot
    )
    return 0
