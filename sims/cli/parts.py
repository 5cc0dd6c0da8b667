"""``decentral parts``: split a log into each assembly's own part, the file ``decentral agent --log`` reads."""

from __future__ import annotations

import argparse
from pathlib import Path

from decentral.errors import InputError
from sims.cli import feedback

__all__ = ["HELP", "add_arguments", "run"]

HELP = "split a log into each assembly's part (NAME.part.json), what `decentral agent --log` reads"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("log", metavar="LOG.json", help="observation log (decentral.log/1)")
    parser.add_argument("-o", "--output", required=True, metavar="DIR",
                        help="folder to write NAME.part.json into (created if missing; parts there are replaced)")
    parser.add_argument("--only", nargs="+", metavar="NAME", default=None,
                        help="write these assemblies' parts only (default: every assembly's)")


def run(args: argparse.Namespace) -> int:
    from sims.io.log_json import read_log
    from sims.io.paths import name_stem
    from sims.runners.parts import part_of, write_part

    log = read_log(args.log)
    names = list(log.assemblies) if args.only is None else list(dict.fromkeys(args.only))
    unknown = [n for n in names if n not in log.assemblies]
    if unknown:
        raise InputError(f"no assembly {unknown[0]!r} in {args.log}", field="--only")
    out = Path(args.output)
    if out.exists() and not out.is_dir():
        raise InputError("is a file; name a folder", source=str(out), field="-o")
    stems = {n: name_stem(n, field="assemblies") for n in names}  # (checked before anything is written)
    out.mkdir(parents=True, exist_ok=True)
    for name in names:
        write_part(out / f"{stems[name]}.part.json", part_of(log, name), name)
    feedback.summary(f"{len(names)} parts written to {out} (one NAME.part.json per assembly)")
    return 0
