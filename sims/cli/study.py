"""``decentral study``: run a declared sweep into a SQLite store, resumably (docs/formats.md).

The spec (TOML: ``name``, ``command``, ``[fixed]``, ``[grid]``) is checked whole before any cell
runs; cells without a row in ``DIR/study.sqlite`` then run on the chosen engine, and each finished
cell's row is committed as it ends. Running the same command again runs only the missing cells.
Library: :mod:`sims.lab.study`.
"""

from __future__ import annotations

import argparse

from sims.cli import feedback

__all__ = ["HELP", "add_arguments", "run"]

HELP = "run a study (a TOML grid of localize or ensemble cells) into DIR/study.sqlite; resumable"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("spec", metavar="SPEC.toml", help="study specification (name, command, [fixed], [grid])")
    parser.add_argument("-o", "--output", required=True, metavar="DIR", help="study directory (holds study.sqlite)")
    parser.add_argument("--engine", choices=("local", "ray"), default="local",
                        help="local: a process pool on this machine (default); ray: Ray tasks, locally or on "
                             "the cluster at --address (pip install 'decentral[ray]')")
    parser.add_argument("--workers", type=int, default=None,
                        help="worker processes (local) or CPUs of a local Ray instance (default: this machine's CPUs)")
    parser.add_argument("--address", default=None, metavar="ADDR",
                        help="ray: a running cluster: HEAD:6379, auto (one started on this machine) or "
                             "ray://HEAD:10001 (Ray Client, from outside the cluster) (default: start a local instance)")
    parser.add_argument("--retry-failed", action="store_true", help="run the cells whose row says 'failed' again")


def run(args: argparse.Namespace) -> int:
    from decentral.errors import InputError
    from sims.lab.study.engines import make_engine
    from sims.lab.study.runner import default_workers, run_study
    from sims.lab.study.spec import read_spec

    if args.workers is not None and args.workers < 1:
        raise InputError(f"must be >= 1, got {args.workers}", field="--workers")
    spec = read_spec(args.spec)
    workers = args.workers or (default_workers() if args.engine == "local" or not args.address else None)
    engine = make_engine(args.engine, workers, args.address)
    with feedback.progress(spec.name, unit="cell", leave=False) as bar:
        result = run_study(spec, args.output, engine, retry_failed=args.retry_failed, progress=bar,
                           on_failed=_FailureLines(tuple(spec.grid)))
    feedback.summary(
        f"{spec.name}: {result.ran} cells run ({result.failed} failed), {result.skipped} already done, "
        f"{result.total} in the grid; wall {result.seconds:.1f} s on {args.engine} -> {result.path}")
    return 0


class _FailureLines:
    """One warning line on stderr per failed cell (its [grid] values and error), the first :attr:`LIMIT` of them."""

    LIMIT = 10

    def __init__(self, keys: tuple[str, ...]) -> None:
        self.keys, self.count = keys, 0

    def __call__(self, cell, row: dict) -> None:
        self.count += 1
        if self.count <= self.LIMIT:
            params = ", ".join(f"{k}={v}" for k, v in cell.params.items() if k in self.keys or not self.keys)
            feedback.warn(f"cell failed ({params}): {row.get('error')}")
        elif self.count == self.LIMIT + 1:
            feedback.warn("more cells failed: their errors are in the store's 'error' column")
