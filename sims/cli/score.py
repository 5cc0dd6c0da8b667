"""``decentral score``: an estimate against ground truth.

Two kinds of input, told apart by content (an ``.npz`` archive or JSON), not by file name:

- a ``decentral.estimate/1`` (JSON) against a ``decentral.truth/1``: the Table I metrics of Liu et al. (2024)
  (positional, relative and angular error, coverage), per assembly and overall;
- an ensemble estimate (``.npz`` with ``position``) against a ``decentral.ensemble_truth/1``
  (``decentral make-ensemble --truth``): Funiak et al.'s global and local RMS centre error in module
  radii (:func:`decentral.ensemble.metrics.evaluate`). The neighbour pairs that fix the scale and
  connect the local regions are the truth file's observed ``pairs``; a truth file without them
  uses the true centres closer than the default infrared sensor's reach.

The table (or ``--json``) goes to stdout; the one-line summary to stderr.
"""

from __future__ import annotations

import argparse
import json

from decentral.errors import InputError
from sims.cli import feedback

__all__ = ["COLUMNS", "HELP", "add_arguments", "run", "format_table"]

HELP = ("score an estimate against ground truth: a decentral.estimate/1 against a decentral.truth/1 "
        "(positional, relative and angular error), or an ensemble estimate .npz against its truth .npz "
        "(global and local RMS)")


#: what every column of the two tables means (``score --help`` prints it; docs/cli.md repeats it)
COLUMNS = """\
columns of a decentral.estimate/1 score (one row per assembly, then "overall"; Liu et al. 2024 Table I,
means over the steps where the assembly is placed, relative to the estimate's reference assembly):
  pos [m]      mean position error, metres
  rel [%]      mean position error divided by the true distance to the reference, percent
  yaw [deg]    mean absolute yaw error, degrees
  coverage     share of the truth's steps at which the assembly is placed ("-" errors: never placed)

columns of an ensemble score (Funiak et al. 2008 Fig. 10; module radii):
  modules      number of modules
  global RMS   RMS centre error after scaling the estimate to the true neighbour spacing and one
               rigid alignment of the whole ensemble
  local RMS    RMS centre error after aligning each region (at most six module diameters across)
               on its own: the error of modules relative to their neighbours
  scale        factor applied to the estimate before aligning it, so that its mean spacing between
               observed neighbours equals the truth's (the model does not forbid overlap; 1 = right size)
  regions      number of regions the local RMS aligned separately

--json prints the same values under their full names (position_m, relative_position_pct, yaw_deg,
coverage; global_rms, local_rms, scale, regions, and pairs: the neighbour pairs used, pairs_from:
"observed" or "true contacts")."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.epilog = COLUMNS
    parser.add_argument("estimate", metavar="EST", help="estimate: decentral.estimate/1 (JSON) or ensemble estimate (.npz)")
    parser.add_argument("truth", metavar="TRUTH", help="ground truth: decentral.truth/1 (JSON) or decentral.ensemble_truth/1 (.npz)")
    parser.add_argument("--json", action="store_true", help="print the full score as JSON")


def format_table(rows: dict[str, dict], first: str = "method") -> str:
    """A fixed-width table of named overall scores (``Score.overall.to_dict()`` values).

    ``first`` heads the column of row names: what the rows are (methods, assemblies, ...).
    """
    fps = any("fps" in r for r in rows.values())
    lines = [f"{first:<28} {'pos [m]':>9} {'rel [%]':>8} {'yaw [deg]':>10} {'coverage':>9}" + (" fps [Hz]" if fps else "")]
    for name, r in rows.items():
        if r["position_m"] is None:
            lines.append(f"{name:<28} {'-':>9} {'-':>8} {'-':>10} {100 * r['coverage']:>8.0f}%")
            continue
        lines.append(f"{name:<28} {r['position_m']:>9.4f} {r['relative_position_pct']:>8.2f} "
                     f"{r['yaw_deg']:>10.2f} {100 * r['coverage']:>8.0f}%" + (f" {r['fps']:>8.0f}" if "fps" in r else ""))
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    from sims.io.ensemble_npz import is_npz

    if is_npz(args.estimate):
        return _run_ensemble(args)
    from decentral.metrics import score_estimate
    from sims.io.log_json import read_estimate
    from sims.simulation.world.truth import read_truth

    estimate = read_estimate(args.estimate)
    truth = read_truth(args.truth)
    try:
        score = score_estimate(truth.poses, estimate)
    except InputError as err:  # what the truth lacks is named in the estimate's fields
        raise err.located(args.estimate) from None
    _check_times_match(score.unmatched_steps, estimate, truth.poses.times, args)
    doc = score.to_dict()
    if not _print_json(args, doc):
        per = {name: s.to_dict() for name, s in score.per_assembly.items()}
        print(format_table({**per, "overall": score.overall.to_dict()},
                           first=f"assembly (relative to {score.reference})"))
    o = score.overall.to_dict()
    if o["position_m"] is None:
        feedback.summary(f"no assembly placed (coverage {100 * o['coverage']:.0f}%)")
    else:
        feedback.summary(f"overall position {o['position_m']:.4f} m, relative {o['relative_position_pct']:.2f} %, "
                         f"yaw {o['yaw_deg']:.2f} deg, coverage {100 * o['coverage']:.0f}%")
    return 0


def _check_times_match(unmatched: int, estimate, truth_times, args: argparse.Namespace) -> None:
    """Refuse an estimate none of whose step times is a truth time; warn when only some are not.

    Without this, an estimate made from another run (or with shifted clocks) would read as
    "no assembly placed": the scorer simply found nothing to compare.
    """
    steps = len(estimate.steps)
    if steps and unmatched == steps:
        raise InputError(f"no estimate step time matches a truth time (first estimate t={estimate.steps[0].t:g}, "
                         f"truth t={truth_times[0]:g}; is {args.truth} the truth of this run?)",
                         source=args.estimate, field="steps[0].t")
    if unmatched:
        feedback.warn(f"{unmatched} of {steps} estimate steps match no truth time and are not scored")


def _print_json(args: argparse.Namespace, doc: dict) -> bool:
    """Refuse a score that is not finite (never printed as NaN/Infinity); print it as JSON with ``--json``.

    Returns whether it was printed (else the caller prints its table).
    """
    from decentral.errors import SolverError
    from sims.io.atomic import first_non_finite

    bad = first_non_finite(doc)
    if bad is not None:
        raise SolverError(f"{args.estimate}: the score's {bad} is not finite against {args.truth}")
    if args.json:
        print(json.dumps(doc, indent=1, allow_nan=False))
    return bool(args.json)


def _run_ensemble(args: argparse.Namespace) -> int:
    from sims.runners.ensemble_run import ensemble_score

    score = ensemble_score(args.estimate, args.truth)
    if not _print_json(args, score):
        print(f"{'modules':>8} {'global RMS [radii]':>19} {'local RMS [radii]':>18} {'scale':>7} {'regions':>8}")
        print(f"{score['modules']:>8} {score['global_rms']:>19.4f} {score['local_rms']:>18.4f} "
              f"{score['scale']:>7.4f} {score['regions']:>8}")
    feedback.summary(f"{score['modules']} modules: global RMS {score['global_rms']:.4f}, "
                     f"local RMS {score['local_rms']:.4f} module radii")
    return 0
