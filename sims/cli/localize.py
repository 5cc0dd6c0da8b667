"""``decentral localize``: a ``decentral.log/1`` in, a ``decentral.estimate/1`` out (CONTRACT §4).

A progress bar counts log steps (with ADMM rounds and messages in ``--mode admm``); one summary
line closes the run. ``--mode admm`` warns on stderr when steps hit ``--max-rounds`` without
converging, and exits with :data:`~sims.cli.main.EXIT_NO_RESULT` (3) when it placed no assembly at
all (the estimate is still written: its ``stats`` say what the network did).
"""

from __future__ import annotations

import argparse
import dataclasses

from decentral.errors import InputError
from decentral.factors import NoiseModel
from sims.cli import feedback
from sims.io.log_json import read_log, write_estimate
from sims.io.paths import check_output
from sims.io.validate import require_range

__all__ = ["HELP", "add_arguments", "run", "ESTIMATORS"]

HELP = "estimate every assembly's pose relative to a reference from an observation log"

#: estimator name -> one-line description (the seed's method and its baselines)
ESTIMATORS = {
    "windowed": "Liu et al. 2024 §IV: radius-depth visual factors + odometry, SDP relaxation, sliding window",
    "bearing": "Liu et al. 2024 §V-C 2 baseline: root-node bearings only (no radius) + odometry",
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("log", metavar="LOG.json", help="observation log (decentral.log/1)")
    parser.add_argument("-o", "--output", required=True, metavar="EST.json", help="estimate to write")
    parser.add_argument("--window", type=int, default=5, help="steps per sliding window K (default 5; 1 = per frame)")
    parser.add_argument("--reference", default=None, help="reference assembly (default: the first listed)")
    parser.add_argument("--mode", choices=("centralized", "admm"), default="centralized",
                        help="joint estimate (default) or one agent per assembly with consensus-ADMM")
    parser.add_argument("--loss", type=float, default=0.0, help="admm: probability that a message is dropped")
    parser.add_argument("--seed", type=int, default=0, help="admm: seed of the simulated network")
    parser.add_argument("--share-forms", choices=("every", "first", "never"), default="every",
                        help="admm: when agents share their pairs' cost forms and start at the joint solution: "
                             "every step (default: each window starts at the joint solution), the first step only, "
                             "or never (plain consensus-ADMM)")
    parser.add_argument("--aggregation", choices=("tree", "broadcast"), default="tree",
                        help="admm: how the shared forms travel once agents know their route to the reference: "
                             "up and down a spanning tree of the view graph (default: messages per agent per "
                             "window bounded by its number of neighbours) or one broadcast per agent (fewer "
                             "rounds, messages grow with the number of assemblies)")
    parser.add_argument("--max-rounds", type=int, default=300, help="admm: round budget per step (default 300)")
    parser.add_argument("--estimator", choices=tuple(ESTIMATORS), default="windowed",
                        help="; ".join(f"{k}: {v}" for k, v in ESTIMATORS.items()))
    parser.add_argument("--solver", choices=("low-rank", "sdp"), default="low-rank",
                        help="low-rank with certificate (default) or the cvxpy/Clarabel SDP reference")
    parser.add_argument("--weighting", choices=("information", "unit"), default="information",
                        help="weight factors by their noise (default) or not at all, as the paper's sums")
    parser.add_argument("--sigma-pixel", type=float, default=NoiseModel.sigma_pixel, help="detection centre std, px")
    parser.add_argument("--sigma-radius", type=float, default=NoiseModel.sigma_radius, help="detection radius std, px")
    parser.add_argument("--sigma-odom-p", type=float, default=NoiseModel.sigma_odom_p, help="odometry step std, m")
    parser.add_argument("--sigma-odom-theta", type=float, default=NoiseModel.sigma_odom_theta,
                        help="odometry yaw step std, rad")


#: command-line noise levels must lie in this range (in their units: px, px, m, rad)
SIGMA_RANGE = (1e-9, 1e6)


def _noise(args: argparse.Namespace) -> NoiseModel:
    for name in ("sigma_pixel", "sigma_radius", "sigma_odom_p", "sigma_odom_theta"):
        require_range(getattr(args, name), "--" + name.replace("_", "-"), *SIGMA_RANGE)
    try:
        return NoiseModel(args.sigma_pixel, args.sigma_radius, args.sigma_odom_p, args.sigma_odom_theta, args.weighting)
    except ValueError as err:
        raise InputError(str(err), field="--sigma-*") from None


def run(args: argparse.Namespace) -> int:
    if args.window < 1:
        raise InputError(f"must be >= 1, got {args.window}", field="--window")
    if not 0.0 <= args.loss < 1.0:
        raise InputError(f"must be in [0, 1), got {args.loss}", field="--loss")
    if args.max_rounds < 1:
        raise InputError(f"must be >= 1, got {args.max_rounds}", field="--max-rounds")
    if args.seed < 0:
        raise InputError(f"must be >= 0, got {args.seed}", field="--seed")
    check_output(args.output, [args.log])
    log = read_log(args.log)
    reference = args.reference or log.assemblies[0]
    if reference not in log.assemblies:
        raise InputError(f"no assembly {reference!r} in {args.log}", field="--reference")
    noise = _noise(args)
    with feedback.progress("localize", total=len(log.steps)) as bar:
        if args.mode == "admm":
            estimate = _run_admm(log, args, noise, reference, bar)
        elif args.estimator == "bearing":
            from decentral.bearing import BearingConfig, estimate_log_bearing

            estimate = estimate_log_bearing(log, BearingConfig(window=args.window, noise=noise), reference, bar)
        else:
            from decentral.estimator import EstimatorConfig, estimate_log

            config = EstimatorConfig(window=args.window, solver=args.solver, noise=noise)
            estimate = estimate_log(log, config, reference, bar)
    write_estimate(args.output, estimate)
    return _report(estimate, args, n_assemblies=len(log.assemblies))


def _not_placed(estimate) -> str:
    """``; not placed: REASON N, ...`` over every (step, assembly) left out, most frequent first; empty if none."""
    from decentral.placement import count_reasons

    reasons = count_reasons(step.unplaced for step in estimate.steps)
    why = ", ".join(f"{code} {n}" for code, n in sorted(reasons.items(), key=lambda kv: -kv[1]))
    return f"; not placed: {why}" if why else ""


def _run_admm(log, args, noise, reference, progress):
    from sims.admm_run import AdmmRunConfig, run_admm

    config = AdmmRunConfig(window=args.window, noise=noise, loss=args.loss, share_forms=args.share_forms,
                           aggregation=args.aggregation, max_rounds=args.max_rounds)
    estimate = run_admm(log, reference, config, seed=args.seed, progress=progress).estimate
    # the contract counts stray tags in every estimate's stats, as the centralized estimator does
    stray = sum(step.stray_detections() for step in log.steps)
    return dataclasses.replace(estimate, stats={**estimate.stats, "stray_detections": stray})


def _report(estimate, args: argparse.Namespace, n_assemblies: int) -> int:
    """Print the summary line and the warnings of a finished run; return the exit status."""
    from sims.cli.main import EXIT_NO_RESULT

    steps = len(estimate.steps)
    placed = sum(len(step.poses) for step in estimate.steps)
    possible = steps * (n_assemblies - 1)
    coverage = (f"coverage {100 * placed / possible:.0f}% ({placed} placements of {possible} assembly-steps"
                f"{_not_placed(estimate)})" if possible else "coverage -")
    stats = estimate.stats
    if args.mode != "admm":
        certified = (f", {stats['certified_windows']}/{stats['windows_solved']} windows certified"
                     if "windows_solved" in stats else "")
        feedback.summary(f"{steps} steps{certified}, {coverage} -> {args.output}")
        if possible and not placed:
            feedback.warn("placed no assembly: no step had observations linking another assembly to the reference")
        return 0
    total = stats["messages"]["total"]
    n_converged = sum(stats["converged_per_step"])
    feedback.summary(f"{steps} steps, {stats['rounds_total']} rounds, {total['sent']} messages "
                     f"({total['bytes_sent'] / 1e6:.2f} MB), converged {n_converged}/{steps} steps, "
                     f"{coverage} -> {args.output}")
    if n_converged < steps:
        feedback.warn(f"consensus did not converge at {steps - n_converged} of {steps} steps within "
                      f"--max-rounds {args.max_rounds}; their estimates are the last iterates")
    if possible and not placed:
        feedback.warn(f"placed no assembly: {total['dropped']} of {total['sent']} messages were dropped "
                      f"(--loss {args.loss:g}) and no estimate reached the reference "
                      f"(exit status {EXIT_NO_RESULT})")
        return EXIT_NO_RESULT
    return 0
