"""``decentral export``: an estimate or a ground truth as per-assembly trajectory files (docs/formats.md).

The input's ``format`` field decides what it is: a ``decentral.estimate/1`` gives one file per
assembly it places, a ``decentral.truth/1`` one per assembly other than the reference, both relative
to the same reference, so that ``evo_ape tum TRUTH_DIR/A1.tum EST_DIR/A1.tum`` (no alignment) gives
the positional error ``decentral score`` reports for A1.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from decentral.errors import InputError
from sims.cli import feedback

__all__ = ["HELP", "add_arguments", "run"]

HELP = "write an estimate or a ground truth as one TUM, KITTI or CSV trajectory file per assembly"


#: sims.io.trajectories.FORMATS (format -> the files it writes), repeated here so that ``--help`` does not
#: import numpy (a test keeps them equal)
FORMATS = {
    "tum": "DIR/<NAME>.tum: lines 't x y z qx qy qz qw' (TUM RGB-D; evo_ape tum)",
    "kitti": "DIR/<NAME>.txt: 3x4 [R|p] row by row per line, and DIR/<NAME>.times.txt (KITTI odometry; evo_ape kitti)",
    "csv": "DIR/<NAME>.csv: header t,x,y,z,theta,qx,qy,qz,qw",
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("input", metavar="EST.json|TRUTH.json",
                        help="a decentral.estimate/1 or a decentral.truth/1 (told apart by its 'format' field)")
    parser.add_argument("-o", "--output", required=True, metavar="DIR", help="output folder (created if needed)")
    parser.add_argument("--format", choices=tuple(FORMATS), default="tum",
                        help="; ".join(f"{k}: {v}" for k, v in FORMATS.items()) + " (default: tum)")
    parser.add_argument("--reference", default=None,
                        help="write poses relative to this assembly (default: the estimate's reference, or the "
                             "truth's 'reference' field; give an estimate's reference here to export its truth "
                             "relative to it)")


def run(args: argparse.Namespace) -> int:
    from sims.io.log_json import ESTIMATE_FORMAT, load_json, parse_estimate
    from sims.io.trajectories import estimate_trajectories, truth_trajectories, write_trajectories
    from sims.simulation.world.truth import TRUTH_FORMAT, parse_truth

    from sims.io.kinds import require_kind

    require_kind(args.input, ESTIMATE_FORMAT, TRUTH_FORMAT)
    doc = load_json(args.input)
    kind = doc.get("format") if isinstance(doc, dict) else None
    try:
        if kind == ESTIMATE_FORMAT:
            trajectories = estimate_trajectories(parse_estimate(doc), args.reference)
        elif kind == TRUTH_FORMAT:
            truth = parse_truth(doc)
            trajectories = truth_trajectories(truth.poses, args.reference or truth.reference)
        else:
            raise InputError(f"expected {ESTIMATE_FORMAT!r} or {TRUTH_FORMAT!r}, got {kind!r}", field="format")
        if Path(args.output).exists() and not Path(args.output).is_dir():
            raise InputError("exists and is not a folder", source=str(args.output), field="-o")
        # checks every name and line before it creates the folder: bad input writes nothing
        written = write_trajectories(trajectories, args.output, args.format)
    except InputError as err:
        if err.field == "reference" and args.reference:
            raise InputError(err.message, field="--reference") from None
        raise err.located(str(args.input)) from None
    outdir = args.output
    feedback.summary(f"{len(trajectories)} assemblies, {len(written)} files ({args.format}) -> {outdir}"
                     + ("" if trajectories else " (no assembly is placed at any step)"))
    return 0
