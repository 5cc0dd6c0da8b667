"""Runners: each takes a log, a problem or recordings plus a config and returns a result (no CLI, no I/O policy).

The command-line modules (:mod:`sims.cli`) parse arguments, call a runner and report; the studies and
experiments call the same runners over grids of cases.
"""

__all__: list[str] = []
