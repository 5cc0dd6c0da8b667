"""``decentral score``: the Table I metrics of Liu et al. (2024) of an estimate against a simulator's ground truth."""

from __future__ import annotations

import argparse
import json

__all__ = ["HELP", "add_arguments", "run", "format_table"]

HELP = "score a decentral.estimate/1 against a decentral.truth/1 (positional, relative and angular error)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("estimate", metavar="EST.json", help="estimate (decentral.estimate/1)")
    parser.add_argument("truth", metavar="TRUTH.json", help="ground truth (decentral.truth/1)")
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
    from decentral.metrics import score_estimate
    from sims.io.log_json import read_estimate
    from sims.world.truth import read_truth

    estimate = read_estimate(args.estimate)
    truth = read_truth(args.truth)
    score = score_estimate(truth.poses, estimate)
    if args.json:
        print(json.dumps(score.to_dict(), indent=1))
    else:
        per = {name: s.to_dict() for name, s in score.per_assembly.items()}
        print(format_table({**per, "overall": score.overall.to_dict()},
                           first=f"assembly (relative to {score.reference})"))
    return 0
