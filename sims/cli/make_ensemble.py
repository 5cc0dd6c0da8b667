"""``decentral make-ensemble``: generate a Funiak et al. 2008 test ensemble (``decentral.ensemble/1`` + truth)."""

from __future__ import annotations

import argparse

from decentral.errors import InputError
from sims.cli import feedback
from sims.io.limits import current_limits, over_limit
from sims.io.paths import check_output

__all__ = ["HELP", "add_arguments", "run"]

HELP = "make a module ensemble (2D settled under gravity, or 3D lattice) and its IR observations"


#: EnsembleSpec field -> the option that sets it
OPTIONS = {"n": "-n", "radius": "--radius", "lattice": "--lattice", "jitter": "--jitter"}


#: the names of sims.simulation.ensembles.generator.SHAPES by dimension, listed here so that ``--help`` does not
#: import the generator (scipy); a test keeps the two equal
SHAPES_2D = ("triple", "sparse", "open", "twin", "funnel", "ring", "blobs", "capture-triple", "capture-sparse",
             "capture-open")
SHAPES_3D = ("sphere", "box", "torus", "dumbbell", "triple3d")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("shape", choices=SHAPES_2D + SHAPES_3D, metavar="SHAPE",
                        help=f"2D container ({', '.join(SHAPES_2D)}) or 3D solid ({', '.join(SHAPES_3D)})")
    parser.add_argument("-n", type=int, default=1000, help="modules requested (default: 1000)")
    parser.add_argument("-o", "--output", required=True, metavar="OBS.npz", help="observations to write")
    parser.add_argument("--truth", metavar="TRUTH.npz", help="also write the true poses here")
    parser.add_argument("--radius", type=float, default=0.05, help="module radius, m (default: 0.05)")
    parser.add_argument("--lattice", choices=("hcp", "cubic"), default="hcp", help="3D lattice (default: hcp)")
    parser.add_argument("--jitter", type=float, default=0.03, help="3D lattice jitter, module radii (default: 0.03)")
    parser.add_argument("--threshold", type=float, default=0.2,
                        help="IR detection threshold, fraction of peak (default: 0.2)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from sims.simulation.ensembles.generator import EnsembleSpec, generate, save_observations, save_truth
    from sims.simulation.ensembles.sensors import SensorModel
    from sims.io.validate import MAX_METRES, MIN_METRES, require_range

    if not 0 < args.threshold < 1:
        raise InputError("must be in (0, 1)", field="--threshold")
    limits = current_limits()
    if args.n > limits.max_modules:
        raise over_limit("module count", args.n, "max_modules", limits.max_modules, field="-n")
    require_range(args.radius, "--radius", MIN_METRES, MAX_METRES)
    check_output(args.output)
    if args.truth:
        check_output(args.truth, [args.output], field="--truth")
    try:
        spec = EnsembleSpec(args.shape, args.n, args.radius, args.lattice, args.jitter,
                            SensorModel(threshold=args.threshold))
    except InputError as err:  # the spec names its fields; the user gave them as options
        raise InputError(err.message, field=OPTIONS.get(err.field, err.field)) from None
    ens = generate(spec, np.random.default_rng(args.seed))
    if args.truth:
        save_truth(args.truth, ens, seed=args.seed)
    save_observations(args.output, ens)
    dropped = f" ({ens.dropped} of {args.n} requested dropped: not connected to the rest)" if ens.dropped else ""
    feedback.summary(f"{ens.n} modules ({ens.dim}D {args.shape}){dropped}, {len(ens.i) // 2} observed pairs, "
                     f"mean degree {len(ens.i) / max(ens.n, 1):.1f} -> {args.output}"
                     + (f", {args.truth}" if args.truth else ""))
    return 0
