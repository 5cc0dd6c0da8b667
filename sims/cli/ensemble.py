"""``decentral ensemble``: ``decentral.ensemble/1`` observations in, module poses out (docs/formats.md).

``--method ncut`` (default) is Funiak et al.'s Algorithm 1; ``incremental``, ``mds``, ``sdp`` and
``bottom-up`` are the baselines of its §VI-E. ``--distributed`` runs Algorithm 1 as one agent per
module over the simulated network (``--loss``: probability that a message is dropped); that runner
lives in :mod:`sims.runners.ensemble_distributed` (``run_distributed``) and this command only calls it, so
if it is not installed the command says so and exits 2. The estimate then also holds ``messages``,
``phase_names`` and ``phase_messages``.

``--tol`` sets the refinement tolerance: the largest gradient entry, in module radii, at which each
level's refinement and the top's stop (Funiak et al. 2008 §VI-B). It is what ``benchmarks/ensemble_messages.py``
varies (``--gtol``, with ``--check-every 5``), so a point of its message figure is
``decentral ensemble OBS.npz -o EST.npz --distributed --tol 0.01 --check-every 5``. Without it each
method keeps its defaults (centralized: levels 1e-3, top 1e-6; distributed: levels 1e-3, top 1e-4).

A progress bar follows the hierarchy (modules placed by leaves, then the top refinement; with
``--distributed``, each stage and the messages so far); one summary line closes the run, and a
warning says when a refinement stopped at its iteration cap instead of at the tolerance, and another
when a 3D ensemble has hinges (:func:`decentral.ensemble.observability.hinge_pairs`: single
observation pairs about which a part can turn without changing the likelihood).
"""

from __future__ import annotations

import argparse
import math
import time
from contextlib import nullcontext

from decentral.errors import InputError
from sims.cli import feedback

__all__ = ["HELP", "METHODS", "add_arguments", "run"]

HELP = "localize every module of an ensemble from neighbour observations (Funiak et al. 2008)"

#: method name -> one-line description
METHODS = {
    "ncut": "Funiak et al. 2008, Algorithm 1: recursive normalized cut, closed-form merges, refinement",
    "incremental": "Funiak et al. 2008 §III-B baseline: breadth-first incremental maximum likelihood",
    "mds": "baseline: classical MDS of hop counts, then refinement",
    "sdp": "baseline: regularized SDP localization (Clarabel), then refinement (size-guarded)",
    "bottom-up": "baseline: bottom-up merging in order of algebraic connectivity",
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("observations", metavar="OBS.npz", help="observations (decentral.ensemble/1)")
    parser.add_argument("-o", "--output", required=True, metavar="EST.npz", help="estimate to write (.npz)")
    parser.add_argument("--method", choices=tuple(METHODS), default="ncut",
                        help="; ".join(f"{k}: {v}" for k, v in METHODS.items()))
    parser.add_argument("--distributed", action="store_true",
                        help="run Algorithm 1 as one agent per module over the simulated network")
    parser.add_argument("--loss", type=float, default=None,
                        help="with --distributed: probability that a message is dropped (default: 0)")
    parser.add_argument("--seed", type=int, default=0,
                        help="seed of the random leaders (and of the simulated network with --distributed) "
                             "(default: 0)")
    parser.add_argument("--tol", type=float, default=None, metavar="GTOL",
                        help="refinement tolerance: largest gradient entry, in module radii, at which every "
                             "level's refinement and the top's stop (default: the method's own, 1e-3 for "
                             "levels and 1e-6 (centralized) or 1e-4 (distributed) for the top)")
    parser.add_argument("--check-every", type=int, default=None, metavar="K",
                        help="with --distributed: refinement iterations between convergence checks (default: 10)")


def _distributed(problem, args, progress=None) -> tuple:
    import numpy as np

    try:
        from sims.runners.ensemble_distributed import run_distributed
    except ImportError:
        raise InputError("the distributed runner (sims.runners.ensemble_distributed) is not available in this "
                         "installation", field="--distributed") from None
    from sims.runners.ensemble_run import distributed_config

    config = distributed_config(args.loss or 0.0, args.tol, args.check_every)
    res = run_distributed(problem, np.random.default_rng(args.seed), config, progress=progress)
    extra = {
        "messages": np.asarray(res.messages, dtype=np.int64),
        "phase_names": np.asarray(list(res.phase_names), dtype=str),
        "phase_messages": np.asarray(res.phase_messages, dtype=np.int64),
        "cost": np.float64(res.cost),
    }
    return res, extra


def _validate(args: argparse.Namespace) -> None:
    for flag, value in (("--loss", args.loss), ("--check-every", args.check_every)):
        if value is not None and not args.distributed:
            raise InputError("only applies with --distributed", field=flag)
    if args.loss is not None and not 0.0 <= args.loss < 1.0:
        raise InputError(f"must be in [0, 1), got {args.loss}", field="--loss")
    if args.tol is not None and not (math.isfinite(args.tol) and args.tol > 0):
        raise InputError(f"must be a positive number (module radii), got {args.tol}", field="--tol")
    if args.check_every is not None and args.check_every < 1:
        raise InputError(f"must be >= 1, got {args.check_every}", field="--check-every")


def run(args: argparse.Namespace) -> int:
    import numpy as np

    _validate(args)
    if args.distributed and args.method != "ncut":
        raise InputError(f"--distributed runs the ncut method only, not {args.method!r}", field="--method")
    if args.seed < 0:
        raise InputError(f"must be >= 0, got {args.seed}", field="--seed")
    from sims.io.ensemble_npz import read_ensemble, write_ensemble_estimate
    from sims.io.limits import current_limits, over_limit
    from sims.io.paths import check_output

    check_output(args.output, [args.observations])
    limits = current_limits()
    problem = read_ensemble(args.observations, limits)
    if args.distributed and problem.n > limits.max_agents:
        raise over_limit("module count", problem.n, "max_agents", limits.max_agents, " for --distributed",
                         source=args.observations, field="n")
    t0, cpu0 = time.perf_counter(), time.process_time()
    if args.distributed:
        with feedback.progress("ensemble", unit="stage") as bar:
            res, extra = _distributed(problem, args, progress=bar)
    else:
        # the baselines report no progress: only the hierarchy gets a bar
        bar = feedback.progress("ensemble", total=problem.n, unit="module") if args.method == "ncut" else nullcontext()
        from sims.runners.ensemble_run import localize

        with bar as progress:
            res = localize(problem, args.method, args.seed, args.tol, progress=progress)
        extra = {"cost": np.float64(res.cost), "iterations_per_module": res.iterations_per_module}
    seconds = time.perf_counter() - t0
    cpu_seconds = time.process_time() - cpu0
    extra["seconds"] = np.float64(seconds)
    extra["cpu_seconds"] = np.float64(cpu_seconds)
    extra["method"] = np.asarray(args.method + ("/distributed" if args.distributed else ""))
    write_ensemble_estimate(args.output, res.estimate, **extra)
    _report(problem, res, args, _timing(seconds, cpu_seconds))
    return 0


def _timing(wall: float, cpu: float) -> str:
    """``wall 18.2 s, CPU 17.9 s``: how long the localization itself took (reading and writing excluded)."""
    return f"wall {wall:.1f} s, CPU {cpu:.1f} s"


def _report(problem, res, args: argparse.Namespace, timing: str) -> None:
    """The summary line and warnings of a finished run."""
    _summarize(problem, res, args, timing)
    _warn_hinges(problem)


def _warn_hinges(problem) -> None:
    """Warn when single observation pairs join parts of a 3D ensemble (the likelihood is flat about them)."""
    from decentral.ensemble.observability import hinge_pairs, hinged_parts

    import numpy as np

    hinges = hinge_pairs(problem)
    if len(hinges):
        shown = ", ".join(f"{i}-{j}" for i, j in hinges[:3]) + (", ..." if len(hinges) > 3 else "")
        loose = int(np.count_nonzero(hinged_parts(problem, hinges)))
        feedback.warn(f"{len(hinges)} observation pair(s) are the only contact between two parts of the "
                      f"ensemble (modules {shown}; {loose} module(s) outside the largest rigid part): in 3D "
                      "the rotation of one part about such a contact is unobservable, so the parts may be "
                      "turned against each other by any angle (each part is right in itself)")


def _summarize(problem, res, args: argparse.Namespace, timing: str) -> None:
    """The summary line, and the warnings about refinements that stopped at their cap."""
    import numpy as np

    head = f"{problem.n} modules ({problem.dim}D), {_method_label(args)}: cost {res.cost:.4g}"
    if args.distributed:
        sent = res.messages
        feedback.summary(f"{head}, messages per module {sent.mean():.1f} (max {int(sent.max())}), "
                         f"{res.rounds} rounds, {res.network['total']['bytes_sent'] / 1e6:.2f} MB, "
                         f"{res.levels} levels, localization {timing} -> {args.output}")
        capped = res.info.get("capped_levels", [])
        if capped:
            feedback.warn(f"distributed refinement did not converge: level(s) {', '.join(map(str, capped))} "
                          "stopped at the iteration cap before reaching the tolerance (0 is the top); "
                          "the estimate is the last iterate")
        return
    iters = res.iterations_per_module
    feedback.summary(f"{head}, refinement iterations per module {np.mean(iters):.1f}, localization {timing} "
                     f"-> {args.output}")
    if res.status != "ok":
        feedback.warn(f"refinement did not converge: {res.status}; the estimate is the best found")


def _method_label(args: argparse.Namespace) -> str:
    """``ncut``, ``ncut distributed (loss 0.2)``: the method as the summary line names it."""
    if not args.distributed:
        return args.method
    return f"{args.method} distributed" + (f" (loss {args.loss:g})" if args.loss else "")
