"""``decentral localize``: a ``decentral.log/1`` in, a ``decentral.estimate/1`` out (docs/formats.md).

A progress bar counts log steps (with ADMM rounds and messages in ``--mode admm``); one summary
line closes the run. ``--mode admm`` warns on stderr (one line, :mod:`sims.runners.run_status`) when its
``stats.status`` is not ``ok`` (steps whose window did not converge within ``--max-rounds``), exits
with :data:`~sims.cli.main.EXIT_NO_RESULT` (3) when it placed no assembly at all, and with 4 under
``--strict`` when some step did not converge (the estimate is still written: its ``stats`` say what
the network did).
"""

from __future__ import annotations

import argparse

from decentral.errors import InputError
from sims.cli import feedback

__all__ = ["HELP", "add_arguments", "run", "ESTIMATORS"]

HELP = "estimate every assembly's pose relative to a reference from an observation log"

#: estimator name -> one-line description (the paper's method and its baselines)
ESTIMATORS = {
    "windowed": "Liu et al. 2024 §IV: radius-depth visual factors + odometry, SDP relaxation, sliding window",
    "bearing": "Liu et al. 2024 §V-C 2 baseline: root-node bearings only (no radius) + odometry",
}


#: options that apply only with ``--mode admm`` (attribute -> default); argparse leaves them None when not given
ADMM_DEFAULTS = {"loss": 0.0, "seed": 0, "share_forms": "every", "aggregation": "tree", "max_rounds": 300,
                 "strict": False, "latency": 0.0005, "jitter": 0.001, "round_period": 0.01, "mtu": 0}
#: options that apply only to the centralized mode (attribute -> default)
CENTRAL_DEFAULTS = {"estimator": "windowed", "solver": "low-rank"}


def _option(attribute: str) -> str:
    return "--" + attribute.replace("_", "-")


def _apply_mode_defaults(args: argparse.Namespace) -> None:
    """Refuse an option given for a mode it does not apply to, then fill in the defaults of the others.

    An option that would be silently ignored (``--loss`` without ``--mode admm``, ``--solver sdp`` with
    ``--mode admm`` or ``--estimator bearing``) is a user's mistake: exit 2 naming it.
    """
    admm = args.mode == "admm"
    for attribute in ADMM_DEFAULTS if not admm else ():
        if getattr(args, attribute) is not None:
            raise InputError("only applies with --mode admm", field=_option(attribute))
    for attribute in CENTRAL_DEFAULTS if admm else ():
        if getattr(args, attribute) is not None:
            raise InputError("does not apply with --mode admm", field=_option(attribute))
    if args.estimator == "bearing" and args.solver is not None:
        raise InputError("only applies with --estimator windowed", field="--solver")
    for attribute, default in {**ADMM_DEFAULTS, **CENTRAL_DEFAULTS}.items():
        if getattr(args, attribute) is None:
            setattr(args, attribute, default)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from decentral.noise import NoiseModel

    parser.add_argument("log", metavar="LOG.json", help="observation log (decentral.log/1)")
    parser.add_argument("-o", "--output", required=True, metavar="EST.json", help="estimate to write")
    parser.add_argument("--window", type=int, default=5, help="steps per sliding window K, 1 = per frame (default: 5)")
    parser.add_argument("--reference", default=None, help="reference assembly (default: the first listed)")
    parser.add_argument("--mode", choices=("centralized", "admm"), default="centralized",
                        help="joint estimate or one agent per assembly with consensus-ADMM (default: centralized)")
    parser.add_argument("--loss", type=float, default=None,
                        help=f"admm: probability that a message is dropped (default: {ADMM_DEFAULTS['loss']})")
    parser.add_argument("--mtu", type=int, default=None,
                        help="admm: --loss is the loss of each datagram of this many bytes (the UDP transport's, "
                             "parity included: large messages are lost more often, as on a radio; agents use 1200) "
                             "instead of each message (default: 0, per message)")
    parser.add_argument("--seed", type=int, default=None,
                        help=f"admm: seed of the simulated network (default: {ADMM_DEFAULTS['seed']})")
    parser.add_argument("--share-forms", choices=("every", "first", "never"), default=None,
                        help="admm: when agents share their pairs' cost forms and start at the joint solution: "
                             "every step (each window starts at the joint solution), the first step only, "
                             f"or never (plain consensus-ADMM) (default: {ADMM_DEFAULTS['share_forms']})")
    parser.add_argument("--aggregation", choices=("tree", "broadcast"), default=None,
                        help="admm: how the shared forms travel once agents know their route to the reference: "
                             "up and down a spanning tree of the view graph (messages per agent per "
                             "window bounded by its number of neighbours) or one broadcast per agent (fewer "
                             "rounds, messages grow with the number of assemblies) "
                             f"(default: {ADMM_DEFAULTS['aggregation']})")
    parser.add_argument("--max-rounds", type=int, default=None,
                        help=f"admm: round budget per step (default: {ADMM_DEFAULTS['max_rounds']})")
    parser.add_argument("--latency", type=float, default=None,
                        help="admm: one-way delay of every simulated link, s (default: 0.0005); with --jitter, "
                             "--round-period and --max-rounds (the rounds between two sensor steps) a simulation "
                             "predicts processes on links of that latency (docs/processes.md)")
    parser.add_argument("--jitter", type=float, default=None,
                        help="admm: uniform extra delay of each copy, 0 to JITTER s (default: 0.001)")
    parser.add_argument("--round-period", type=float, default=None,
                        help="admm: simulated seconds per round (default: 0.01)")
    parser.add_argument("--strict", action="store_true", default=None,
                        help="admm: exit with status 4 when stats.status is not 'ok' (a step did not converge); "
                             "the estimate is written either way")
    parser.add_argument("--estimator", choices=tuple(ESTIMATORS), default=None,
                        help="centralized: " + "; ".join(f"{k}: {v}" for k, v in ESTIMATORS.items())
                             + f" (default: {CENTRAL_DEFAULTS['estimator']})")
    parser.add_argument("--solver", choices=("low-rank", "sdp"), default=None,
                        help="centralized windowed: low-rank with certificate or the cvxpy/Clarabel SDP reference "
                             f"(default: {CENTRAL_DEFAULTS['solver']})")
    parser.add_argument("--weighting", choices=("information", "unit"), default="information",
                        help="weight factors by their noise or not at all, as the paper's sums (default: information)")
    parser.add_argument("--sigma-pixel", type=float, default=NoiseModel.sigma_pixel,
                        help=f"detection centre std, px (default: {NoiseModel.sigma_pixel})")
    parser.add_argument("--sigma-radius", type=float, default=NoiseModel.sigma_radius,
                        help=f"detection radius std, px (default: {NoiseModel.sigma_radius})")
    parser.add_argument("--sigma-odom-p", type=float, default=NoiseModel.sigma_odom_p,
                        help=f"odometry step std, m (default: {NoiseModel.sigma_odom_p})")
    parser.add_argument("--sigma-odom-theta", type=float, default=NoiseModel.sigma_odom_theta,
                        help=f"odometry yaw step std, rad (default: {NoiseModel.sigma_odom_theta})")


#: command-line noise levels must lie in this range (in their units: px, px, m, rad)
SIGMA_RANGE = (1e-9, 1e6)


def _noise(args: argparse.Namespace):
    from decentral.noise import NoiseModel
    from sims.io.validate import require_range

    for name in ("sigma_pixel", "sigma_radius", "sigma_odom_p", "sigma_odom_theta"):
        require_range(getattr(args, name), "--" + name.replace("_", "-"), *SIGMA_RANGE)
    try:
        return NoiseModel(args.sigma_pixel, args.sigma_radius, args.sigma_odom_p, args.sigma_odom_theta, args.weighting)
    except ValueError as err:
        raise InputError(str(err), field="--sigma-*") from None


def run(args: argparse.Namespace) -> int:
    from sims.io.log_json import read_log, write_estimate
    from sims.io.paths import check_output

    _apply_mode_defaults(args)
    if args.window < 1:
        raise InputError(f"must be >= 1, got {args.window}", field="--window")
    if not 0.0 <= args.loss < 1.0:
        raise InputError(f"must be in [0, 1), got {args.loss}", field="--loss")
    if args.max_rounds < 1:
        raise InputError(f"must be >= 1, got {args.max_rounds}", field="--max-rounds")
    if args.mtu and not 64 <= args.mtu <= 65507:
        raise InputError(f"must be 0 or a datagram size of 64-65507 bytes, got {args.mtu}", field="--mtu")
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
    from decentral.unplaced import count_reasons

    reasons = count_reasons(step.unplaced for step in estimate.steps)
    why = ", ".join(f"{code} {n}" for code, n in sorted(reasons.items(), key=lambda kv: -kv[1]))
    return f"; not placed: {why}" if why else ""


def _run_admm(log, args, noise, reference, progress):
    from sims.runners.admm_run import AdmmRunConfig, run_admm

    for name in ("latency", "jitter"):
        if not 0.0 <= getattr(args, name) < 60.0:
            raise InputError(f"must be in [0, 60) s, got {getattr(args, name)}", field=f"--{name}")
    if not 0.0 < args.round_period < 60.0:
        raise InputError(f"must be in (0, 60) s, got {args.round_period}", field="--round-period")
    config = AdmmRunConfig(window=args.window, noise=noise, loss=args.loss, share_forms=args.share_forms,
                           aggregation=args.aggregation, max_rounds=args.max_rounds, latency=args.latency,
                           jitter=args.jitter, round_period=args.round_period, mtu=args.mtu)
    return run_admm(log, reference, config, seed=args.seed, progress=progress).estimate


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

    strict = feedback.report_status(stats, steps, args.strict)  # one line: how many steps did not converge, and why
    if possible and not placed:
        feedback.warn(f"placed no assembly: {total['dropped']} of {total['sent']} messages were dropped "
                      f"(--loss {args.loss:g}) and no estimate reached the reference "
                      f"(exit status {EXIT_NO_RESULT})")
        return EXIT_NO_RESULT
    return strict
