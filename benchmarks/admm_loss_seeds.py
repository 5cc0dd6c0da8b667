"""Robustness of the decentralized estimator under heavy loss, over many network seeds.

One network seed says little under loss (``benchmarks/admm.py`` runs one), so this program runs the
same log over several network seeds and reports, per seed and step, the ADMM rounds, whether every
agent reported convergence, and the largest gap between the reference agent's estimate and the
centralized joint estimate (position, yaw), plus whether the two place the same assemblies.

Fixed inputs: the ``multi`` ring with 4 assemblies (scenario seed 1, 6 steps), K = 5, i.i.d. loss
0.5 and 0.3 on every link, round cap 600, the default agents (shared forms every window, tree
aggregation), network seeds 0-7. Step 0 is the cold start (broadcast), steps 1-5 the steady state.

Run ``python benchmarks/admm_loss_seeds.py [--loss 0.5 0.3] [--seeds 8] [--assemblies 4]``; writes
``OUT/admm_loss_seeds.json``. The reference for every figure is the centralized
estimator on the same log, computed in the same run.
"""

from __future__ import annotations

import _common  # noqa: F401  (pins BLAS threads before numpy loads)

import time

import numpy as np

from _common import machine, parser, save
from decentral.estimator import EstimatorConfig, estimate_log
from decentral.metrics import estimate_gap
from decentral.observations import Estimate
from sims.runners.admm_run import AdmmRunConfig, run_admm
from sims.simulation.scenarios import get_scenario, simulate


def _step_gap(central: Estimate, decentral: Estimate, k: int) -> tuple[float, float, int]:
    one = lambda e: Estimate(e.reference, (e.steps[k],), {})  # noqa: E731
    dp, dth, mismatched = estimate_gap(one(central), one(decentral))
    return float(dp), float(np.degrees(dth)), int(mismatched)


def main(argv=None) -> int:
    ap = parser(__doc__)
    ap.add_argument("--loss", type=float, nargs="+", default=[0.5, 0.3])
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--assemblies", type=int, default=4)
    ap.add_argument("--steps", type=int, default=6)
    ap.add_argument("--max-rounds", type=int, default=600)
    args = ap.parse_args(argv)
    sim = simulate(get_scenario("multi", n_assemblies=args.assemblies, steps=args.steps), seed=1)
    central = estimate_log(sim.log, EstimatorConfig(window=5))
    start = time.process_time()
    runs = []
    for loss in args.loss:
        for seed in range(args.seeds):
            run = run_admm(sim.log, config=AdmmRunConfig(window=5, loss=loss, max_rounds=args.max_rounds), seed=seed)
            for k, rounds in enumerate(run.rounds):
                dp, dth, mismatched = _step_gap(central, run.estimate, k)
                runs.append({"loss": loss, "seed": seed, "step": k, "rounds": rounds,
                             "converged": run.converged[k], "gap_mm": 1e3 * dp, "gap_deg": dth,
                             "placed_differently": mismatched})
                print(f"loss {loss:.1f} seed {seed} step {k}: {rounds:4d} rounds, converged {run.converged[k]}, "
                      f"gap {1e3 * dp:.3f} mm {dth:.4f} deg, placed differently {mismatched}")
    summary = {}
    for loss in args.loss:
        rows = [r for r in runs if r["loss"] == loss]
        cold = [r for r in rows if r["step"] == 0]
        steady = [r for r in rows if r["step"] > 0]
        summary[f"{loss:.2f}"] = {
            "all_converged": all(r["converged"] for r in rows),
            "largest_gap_mm": max(r["gap_mm"] for r in rows),
            "largest_gap_deg": max(r["gap_deg"] for r in rows),
            "steps_placed_differently": sum(r["placed_differently"] > 0 for r in rows),
            "cold_start_rounds": [r["rounds"] for r in cold],
            "steady_rounds_median": float(np.median([r["rounds"] for r in steady])),
            "steady_rounds_mean": float(np.mean([r["rounds"] for r in steady])),
            "steady_rounds_max": max(r["rounds"] for r in steady),
        }
    save("admm_loss_seeds", {
        "benchmark": "admm_loss_seeds",
        "parameters": {"scenario": "multi", "assemblies": args.assemblies, "steps": args.steps, "scenario_seed": 1,
                       "window": 5, "losses": args.loss, "network_seeds": list(range(args.seeds)),
                       "max_rounds": args.max_rounds, "agents": "AdmmRunConfig defaults (share_forms every, tree)"},
        "reference": "centralized joint estimate (decentral.estimator.estimate_log) on the same log",
        "summary": summary,
        "runs": runs,
        "cpu_seconds": time.process_time() - start,
        "machine": machine(),
    }, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
