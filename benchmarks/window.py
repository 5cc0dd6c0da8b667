"""Window throughput of Liu et al.'s estimator: low-rank + certificate vs the Clarabel SDP vs a naive loop.

For 2, 5 and 20 assemblies and windows K in {1, 3, 5, 10}, the time of one full window (building
its quadratic form, eliminating positions, solving the relaxation, certifying, recovering positions
and deciding placeability) for both solvers, as windows per second; plus, on a whole pairwise log
with K = 5, the ratio against a naive loop that builds a fresh cvxpy problem of Liu et al.'s P3 as
printed for every window. Single core (BLAS threads pinned to 1).

Targets: pairwise K=5 >= 500 windows/s with certificate; >= 15x the naive loop on a whole
log; a 20-assembly joint window well under a second.

Usage: ``python benchmarks/window.py [--quick]``; writes ``OUT/window.json``.
"""

from __future__ import annotations

import time

from _common import machine, parser, save, timed  # noqa: I001  (pins threads before numpy)

import numpy as np

from decentral.estimator import EstimatorConfig, solve_window
from decentral.factors import NoiseModel, measure_log
from decentral.relaxation import recover_positions, reduce_rotations, solve_literal_primal
from decentral.window import build_window
from sims.simulation.scenarios import get_scenario, simulate


#: the SDP reference is run only up to this many rotations (its PSD cone is dense after eliminating positions)
SDP_MAX_VARIABLES = 50


def scenario_log(n: int, steps: int, seed: int = 0):
    """A ring of ``n`` assemblies each watching the next (cyclic view graph)."""
    return simulate(get_scenario("multi", n_assemblies=n, steps=steps), seed=seed).log


def full_windows(measurements, K: int, reference: str, limit: int):
    """Up to ``limit`` windows of full length K that hold the reference."""
    out = []
    for k in range(K - 1, len(measurements)):
        problem = build_window(measurements, range(k - K + 1, k + 1), reference)
        if problem is not None:
            out.append((k, problem))
        if len(out) >= limit:
            break
    return out


def window_rate(measurements, K: int, reference: str, solver: str, limit: int, budget_s: float) -> dict:
    """Median seconds per full window (build + solve + certify + positions + placeability)."""
    config = EstimatorConfig(window=K, solver=solver)
    times, certified, sizes, solvers = [], [], [], []
    start = time.perf_counter()
    windows = full_windows(measurements, K, reference, limit)
    if solver == "sdp" and windows and windows[0][1].m > SDP_MAX_VARIABLES:
        return {"windows": 0, "variables": windows[0][1].m, "skipped": f"dense {2 * windows[0][1].m}x"
                f"{2 * windows[0][1].m} PSD cone: Clarabel needs minutes per window (see README)"}
    for k, problem in windows:
        if solver == "sdp" and not times:
            solve_window(problem, (reference, k), config)  # first solve of a size builds the cvxpy problem
        t0 = time.perf_counter()
        problem = build_window(measurements, range(k - K + 1, k + 1), reference)
        solved = solve_window(problem, (reference, k), config)
        times.append(time.perf_counter() - t0)
        certified.append(solved.relaxation.certified)
        sizes.append(problem.m)
        solvers.append(solved.relaxation.solver)
        if time.perf_counter() - start > budget_s:
            break
    median = float(np.median(times))
    return {"windows": len(times), "variables": int(np.median(sizes)), "median_s": median,
            "windows_per_s": 1.0 / median, "certified_fraction": float(np.mean(certified)),
            "solver_use": {name: solvers.count(name) for name in sorted(set(solvers))}}


def whole_log(measurements, K: int, reference: str, naive: bool) -> tuple[float, int]:
    """Seconds to run every window of a log with the fast path or the naive fresh-cvxpy loop."""
    config = EstimatorConfig(window=K)
    count = 0
    start = time.perf_counter()
    for k in range(len(measurements)):
        problem = build_window(measurements, range(max(0, k - K + 1), k + 1), reference)
        if problem is None:
            continue
        count += 1
        if naive:
            Q = reduce_rotations(problem.M, problem.m)
            res = solve_literal_primal(Q)
            recover_positions(problem.M, res.theta, problem.b_z)
        else:
            solve_window(problem, (reference, k), config)
    return time.perf_counter() - start, count


def main(argv=None) -> None:
    ap = parser(__doc__)
    ap.add_argument("--quick", action="store_true", help="fewer windows and repeats (a smoke run)")
    args = ap.parse_args(argv)
    limit, budget = (5, 5.0) if args.quick else (40, 60.0)
    grid = []
    for n in (2, 5, 20):
        log = scenario_log(n, steps=60)
        measurements, measure_s = timed(measure_log, log, NoiseModel())
        reference = log.assemblies[0]
        for K in (1, 3, 5, 10):
            for solver in ("low-rank", "sdp"):
                sdp_limit = limit if n <= 5 else 3
                row = window_rate(measurements, K, reference, solver, limit if solver == "low-rank" else sdp_limit,
                                  budget)
                row.update({"assemblies": n, "K": K, "solver": solver,
                            "measure_s_per_step": measure_s / len(log.steps)})
                grid.append(row)
                print(row, flush=True)
    # whole-log comparison, pairwise K=5
    log = scenario_log(2, steps=20 if args.quick else 60, seed=1)
    measurements = measure_log(log, NoiseModel())
    reference = log.assemblies[0]
    fast_runs = [whole_log(measurements, 5, reference, naive=False)[0] for _ in range(3 if args.quick else 5)]
    naive_s, n_windows = whole_log(measurements, 5, reference, naive=True)
    fast_s = float(np.median(fast_runs))
    pair = next(r for r in grid if r["assemblies"] == 2 and r["K"] == 5 and r["solver"] == "low-rank")
    big = next(r for r in grid if r["assemblies"] == 20 and r["K"] == 5 and r["solver"] == "low-rank")
    result = {
        "benchmark": "window",
        "parameters": {"scenario": "multi (ring, cyclic view graph)", "steps": 60, "quick": args.quick},
        "grid": grid,
        "whole_log": {"assemblies": 2, "K": 5, "windows": n_windows, "fast_s_median": fast_s,
                      "naive_fresh_cvxpy_s": naive_s, "speedup_vs_naive": naive_s / fast_s},
        "targets": {
            "pairwise_K5_windows_per_s": pair["windows_per_s"], "pairwise_K5_target": 500,
            "speedup_vs_naive": naive_s / fast_s, "speedup_target": 15,
            "joint20_K5_seconds": big["median_s"], "joint20_target_s": 1.0,
        },
        "machine": machine(),
    }
    save("window", result, args.out)


if __name__ == "__main__":
    main()
