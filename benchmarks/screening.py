"""Cost of the lie tests per window: screening a window's forms against one joint solve of them.

Every window an agent solves (the tree's root, or every agent in a broadcast window) is first screened
for a lying member (:func:`decentral.consistency.screen_members`: the chi-square test of every member,
then the class-by-class tests, about three re-solves per member). This measures, on the windows the
agents of rings of 5, 8 and 12 assemblies actually screen with every member's forms (``multi``
scenario, captured from the simulated runner), the median CPU time of the screening and of one :func:`decentral.admm.solve_joint`
of the same forms (the reference, measured in the same run), and their ratio: what the lie tests cost
in joint solves. Single core (BLAS threads pinned to 1).

Usage: ``python benchmarks/screening.py [--sizes 5 8 12] [--steps 8] [--reps 5]``; writes
``OUT/screening.json``.
"""

from __future__ import annotations

import time

from _common import machine, parser, save  # noqa: I001  (pins threads before numpy)

import numpy as np

import protocols.window_share as window_share
from decentral.admm import solve_joint
from decentral.consistency import screen_members
from sims.runners.admm_run import AdmmRunConfig, run_admm
from sims.simulation.scenarios import get_scenario, simulate


def captured_windows(n: int, steps: int, seed: int) -> list:
    """The ``(forms, gauge, value, options)`` of every screening the agents of an ``n``-ring ran (windows of more
    members than :data:`protocols.window_share.SCREEN_MAX_MEMBERS` screened too, to measure what they would cost)."""
    calls = []
    screen = window_share.screen_members

    def record(problems, gauge, value=None, **options):
        calls.append((list(problems), gauge, value, options))
        return screen(problems, gauge, value, **options)

    window_share.screen_members = record
    limit, window_share.SCREEN_MAX_MEMBERS = window_share.SCREEN_MAX_MEMBERS, max(n, window_share.SCREEN_MAX_MEMBERS)
    try:
        run_admm(simulate(get_scenario("multi", n_assemblies=n, steps=steps), seed=seed).log,
                 config=AdmmRunConfig(max_rounds=40))
    finally:
        window_share.screen_members, window_share.SCREEN_MAX_MEMBERS = screen, limit
    return calls


def cpu_median(fn, reps: int) -> float:
    """Median process CPU time (s) of ``reps`` calls after one untimed call."""
    fn()
    out = []
    for _ in range(reps):
        t0 = time.process_time()
        fn()
        out.append(time.process_time() - t0)
    return float(np.median(out))


def main() -> None:
    ap = parser(__doc__)
    ap.add_argument("--sizes", type=int, nargs="+", default=[5, 8, 12])
    ap.add_argument("--steps", type=int, default=8)
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    rows = []
    for n in args.sizes:
        windows = captured_windows(n, args.steps, args.seed)
        # the windows holding every member's forms, with the class tests (the partial ones on the way up are cheaper)
        full = [w for w in windows if w[3].get("classes", True) and len({k[0] for p in w[0] for k in p.keys}) == n]
        screen_s, solve_s, forms = [], [], []
        for problems, gauge, value, options in full:
            screen_s.append(cpu_median(lambda: screen_members(problems, gauge, value, **options), args.reps))
            solve_s.append(cpu_median(lambda: solve_joint(problems, gauge, value), args.reps))
            forms.append(len(problems))
        row = {"assemblies": n, "windows": len(full), "forms_median": float(np.median(forms)) if forms else 0,
               "screen_ms_median": 1e3 * float(np.median(screen_s)) if full else None,
               "solve_ms_median": 1e3 * float(np.median(solve_s)) if full else None,
               "ratio_median": float(np.median(np.divide(screen_s, solve_s))) if full else None}
        rows.append(row)
        if not full:
            print(f"{n:3d} assemblies: no window holding every member's forms was screened")
            continue
        print(f"{n:3d} assemblies: {row['windows']} windows, {row['forms_median']:.0f} forms, screening "
              f"{row['screen_ms_median']:.1f} ms = {row['ratio_median']:.1f} joint solves ({row['solve_ms_median']:.2f} ms)")
    save("screening", {"benchmark": "screening", "config": vars(args) | {"out": str(args.out)}, "rows": rows,
                       "machine": machine()}, args.out)


if __name__ == "__main__":
    main()
