"""``decentral ensemble``: ``decentral.ensemble/1`` observations in, module poses out (CONTRACT §3-4).

``--method ncut`` (default) is seed 003's Algorithm 1; ``incremental``, ``mds``, ``sdp`` and
``bottom-up`` are the baselines of its §VI-E. ``--distributed`` runs Algorithm 1 as one agent per
module over the simulated network (``--loss``: probability that a message is dropped); that runner
lives in :mod:`sims.ensembles.distributed` (``run_distributed``) and this command only calls it, so
if it is not installed the command says so and exits 2. The estimate then also holds ``messages``,
``phase_names`` and ``phase_messages``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from decentral.errors import InputError

__all__ = ["HELP", "METHODS", "add_arguments", "run", "localize"]

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
                        help="with --distributed: probability that a message is dropped (default 0)")
    parser.add_argument("--seed", type=int, default=0,
                        help="seed of the random leaders (and of the simulated network with --distributed)")


def localize(problem, method: str, seed: int):
    """Run a centralized ``method`` on ``problem``; returns a LocalizationResult (no I/O)."""
    rng = np.random.default_rng(seed)
    if method == "ncut":
        from decentral.ensemble.hierarchical import normcut_localize

        return normcut_localize(problem, rng)
    from decentral.ensemble import baselines

    if method == "incremental":
        return baselines.incremental_localize(problem)
    if method == "mds":
        return baselines.classical_mds(problem)
    if method == "sdp":
        return baselines.sdp_localize(problem)
    if method == "bottom-up":
        return baselines.bottom_up_localize(problem, rng)
    raise InputError(f"unknown method {method!r}", field="--method")


def _distributed(problem, args) -> tuple:
    try:
        from sims.ensembles.distributed import DistributedConfig, run_distributed
    except ImportError:
        raise InputError("the distributed runner (sims.ensembles.distributed) is not available in this "
                         "installation", field="--distributed") from None
    res = run_distributed(problem, np.random.default_rng(args.seed), DistributedConfig(loss=args.loss or 0.0))
    extra = {
        "messages": np.asarray(res.messages, dtype=np.int64),
        "phase_names": np.asarray(list(res.phase_names), dtype=str),
        "phase_messages": np.asarray(res.phase_messages, dtype=np.int64),
        "cost": np.float64(res.cost),
    }
    return res.estimate, extra


def run(args: argparse.Namespace) -> int:
    if args.loss is not None and not args.distributed:
        raise InputError("only applies with --distributed", field="--loss")
    if args.loss is not None and not 0.0 <= args.loss < 1.0:
        raise InputError(f"must be in [0, 1), got {args.loss}", field="--loss")
    if args.distributed and args.method != "ncut":
        raise InputError(f"--distributed runs the ncut method only, not {args.method!r}", field="--method")
    from sims.io.ensemble_npz import read_ensemble, write_ensemble_estimate

    problem = read_ensemble(args.observations)
    t0 = time.perf_counter()
    if args.distributed:
        estimate, extra = _distributed(problem, args)
    else:
        res = localize(problem, args.method, args.seed)
        estimate = res.estimate
        extra = {"cost": np.float64(res.cost), "iterations_per_module": res.iterations_per_module}
    extra["seconds"] = np.float64(time.perf_counter() - t0)
    extra["method"] = np.asarray(args.method + ("/distributed" if args.distributed else ""))
    write_ensemble_estimate(args.output, estimate, **extra)
    return 0
