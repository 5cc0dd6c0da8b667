"""``decentral experiment``: Liu et al.'s experiments reproduced on rendered frames (JSON + PNG).

``decentral experiment table1 -o OUTDIR [--seeds 2] [--steps 60] [--clean] [--detector learned]`` writes
``OUTDIR/table1.json``, ``table1.md`` and ``table1.png`` (Table I: ours vs bearing vs AprilTag);
``decentral experiment reconfig -o OUTDIR [--steps 80]`` writes ``OUTDIR/reconfig.json`` and
``reconfig.png`` (Fig. 4: error over time as nodes are occluded and re-appear).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from decentral.errors import InputError
from sims.cli import feedback

__all__ = ["HELP", "add_arguments", "run"]


def _plot_atomic(plot, result, target: Path) -> None:
    """``plot(result, path)`` into a temporary file renamed to ``target``; removed on any failure."""
    tmp = target.with_name(f".{target.stem}.part{target.suffix}")  # matplotlib picks the format by suffix
    try:
        plot(result, tmp)
        tmp.replace(target)
    finally:
        tmp.unlink(missing_ok=True)


HELP = "reproduce Table I or Fig. 4 of Liu et al. (2024) on rendered frames (writes JSON and a PNG plot)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("name", choices=("table1", "reconfig"), help="which experiment")
    parser.add_argument("-o", "--output", required=True, metavar="OUTDIR", help="output folder (created if needed)")
    parser.add_argument("--seeds", type=int, default=2, help="random seeds (table1; default 2)")
    parser.add_argument("--steps", type=int, default=None, help="steps per run (default: table1 60, reconfig 80)")
    parser.add_argument("--clean", action="store_true", help="render without noise, blur or exposure changes")
    # (agents.perception.detectors.DETECTORS written out: importing it loads OpenCV)
    parser.add_argument("--detector", choices=("learned", "hough", "rim", "symmetry"), default="learned",
                        help="circle detector of the perception front end (default: learned)")


def run(args: argparse.Namespace) -> int:
    from sims.lab.experiments.table1 import TableConfig, plot_reconfig, plot_table1, run_reconfig, run_table1, table_markdown
    from sims.io.atomic import write_atomic, write_json_atomic

    if args.seeds < 1:
        raise InputError("must be at least 1", field="--seeds")
    if args.steps is not None and args.steps < 6:
        raise InputError("must be at least 6", field="--steps")
    out = Path(args.output)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise InputError(f"cannot create output folder ({err.strerror})", source=str(out)) from None

    if args.name == "table1":
        with feedback.progress("table1", unit="stage") as bar:
            result = run_table1(TableConfig(seeds=args.seeds, steps=args.steps or 60, clean=args.clean,
                                            detector=args.detector), progress=bar)
        write_json_atomic(out / "table1.json", result)
        md = table_markdown(result)
        write_atomic(out / "table1.md", lambda fh: fh.write(md))
        _plot_atomic(plot_table1, result, out / "table1.png")
        print(md, end="")
        ours = next(iter(result["table_mean_over_seeds"].values()))
        headline = ("nothing placed" if ours["position_m"] is None else
                    f"ours {ours['position_m']:.4f} m, {ours['yaw_deg']:.2f} deg, coverage {100 * ours['coverage']:.0f}%")
        feedback.summary(f"{args.seeds} seeds: {headline} -> {out / 'table1.json'}, table1.md, table1.png")
    else:
        with feedback.progress("reconfig", unit="stage") as bar:
            result = run_reconfig(TableConfig(seeds=1, steps=args.steps or 80, clean=args.clean,
                                                detector=args.detector), progress=bar)
        write_json_atomic(out / "reconfig.json", result)
        _plot_atomic(plot_reconfig, result, out / "reconfig.png")
        steps = len(next(iter(result["series"].values()))["t"]) if result["series"] else 0
        feedback.summary(f"{steps} steps, targets {', '.join(result['series']) or 'none'} -> {out / 'reconfig.json'}, reconfig.png")
    return 0
