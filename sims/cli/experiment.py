"""``decentral experiment``: seed 000's experiments reproduced on rendered frames (JSON + PNG).

``decentral experiment table1 -o OUTDIR [--seeds 2] [--steps 60] [--clean]`` writes
``OUTDIR/table1.json``, ``table1.md`` and ``table1.png`` (Table I: ours vs bearing vs AprilTag);
``decentral experiment reconfig -o OUTDIR [--steps 80]`` writes ``OUTDIR/reconfig.json`` and
``reconfig.png`` (Fig. 4: error over time as nodes are occluded and re-appear).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from decentral.errors import InputError

__all__ = ["HELP", "add_arguments", "run"]

HELP = "reproduce Table I or Fig. 4 of Liu et al. (2024) on rendered frames (writes JSON and a PNG plot)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("name", choices=("table1", "reconfig"), help="which experiment")
    parser.add_argument("-o", "--output", required=True, metavar="OUTDIR", help="output folder (created if needed)")
    parser.add_argument("--seeds", type=int, default=2, help="random seeds (table1; default 2)")
    parser.add_argument("--steps", type=int, default=None, help="steps per run (default: table1 60, reconfig 80)")
    parser.add_argument("--clean", action="store_true", help="render without noise, blur or exposure changes")


def run(args: argparse.Namespace) -> int:
    from sims.experiments.table1 import TableConfig, plot_reconfig, plot_table1, run_reconfig, run_table1, table_markdown
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

    def tell(msg: str) -> None:
        print(f"decentral experiment {args.name}: {msg}", file=sys.stderr)

    if args.name == "table1":
        result = run_table1(TableConfig(seeds=args.seeds, steps=args.steps or 60, clean=args.clean), progress=tell)
        write_json_atomic(out / "table1.json", result)
        md = table_markdown(result)
        write_atomic(out / "table1.md", lambda fh: fh.write(md))
        tmp = out / ".table1.png.part.png"
        plot_table1(result, tmp)
        tmp.replace(out / "table1.png")
        print(md, end="")
    else:
        result = run_reconfig(TableConfig(seeds=1, steps=args.steps or 80, clean=args.clean))
        write_json_atomic(out / "reconfig.json", result)
        tmp = out / ".reconfig.png.part.png"
        plot_reconfig(result, tmp)
        tmp.replace(out / "reconfig.png")
        print(f"reconfig: {out / 'reconfig.json'}, {out / 'reconfig.png'}")
    return 0
