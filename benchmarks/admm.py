"""Benchmark of the decentralized estimator (consensus-ADMM agents over the simulated network).

Fixed inputs: ``multi`` / ``ring64`` ring scenarios (seed 1), K = 5, the default ADMM and network
parameters (round period 10 ms, latency 0.5 ms, jitter 1 ms). Measured:

* rounds and messages to converge vs number of assemblies (loss 0) and vs loss rate (0 - 50 %);
* messages per agent per window vs the agent's degree (neighbours in the view graph);
* bytes per agent per second at 5 Hz (one window per 0.2 s frame);
* wall time per round (all agents, one process), with the centralized estimator's time per window
  on the same logs as the in-run reference.

Run ``OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python benchmarks/admm.py [--quick]``; writes
``benchmarks/results/admm.json`` and ``benchmarks/results/admm.png``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from decentral.estimator import EstimatorConfig, estimate_log  # noqa: E402
from sims.admm_run import AdmmRunConfig, run_admm  # noqa: E402
from sims.io.atomic import write_atomic, write_json_atomic  # noqa: E402
from sims.scenarios import get_scenario, simulate  # noqa: E402

ADMM_KINDS = ("admm.primal", "admm.dual")


def _gap(central, decentral):
    dp = dth = 0.0
    for a, b in zip(central.steps, decentral.steps):
        for name in set(a.poses) & set(b.poses):
            dp = max(dp, float(np.linalg.norm(a.poses[name].p - b.poses[name].p)))
            dth = max(dth, abs(float(np.angle(np.exp(1j * (a.poses[name].theta - b.poses[name].theta))))))
    return dp, float(np.degrees(dth))


def one_run(n: int, steps: int, loss: float, seed: int = 1, max_rounds: int = 600) -> dict:
    scenario = get_scenario("multi" if n <= 16 else "ring64", n_assemblies=n, steps=steps)
    sim = simulate(scenario, seed=seed)
    t0 = time.perf_counter()
    central = estimate_log(sim.log, EstimatorConfig(window=5))
    central_s = time.perf_counter() - t0
    run = run_admm(sim.log, config=AdmmRunConfig(window=5, loss=loss, max_rounds=max_rounds), seed=seed)
    st = run.stats
    msgs = st["messages"]
    admm_sent = sum(msgs["per_kind"].get(k, {}).get("sent", 0) for k in ADMM_KINDS)
    agents = {}
    for name, a in st["agents"].items():
        sent = msgs["per_sender"].get(name, {})
        agents[name] = {"degree": len(a["neighbours"]), "messages_per_window": sent.get("sent", 0) / steps,
                        "bytes_per_second_5hz": sent.get("bytes_sent", 0) / steps * 5.0}
    dp, dth = _gap(central, run.estimate)
    return {
        "n": n, "steps": steps, "loss": loss,
        "rounds_per_step": list(run.rounds), "rounds_last_step": run.rounds[-1],
        "converged_all_steps": bool(all(run.converged)),
        "messages_total": msgs["total"]["sent"], "admm_messages": admm_sent,
        "messages_per_kind": {k: v["sent"] for k, v in msgs["per_kind"].items()},
        "messages_per_agent_per_window": admm_sent / n / steps,
        "bytes_per_agent_per_second_5hz": msgs["total"]["bytes_sent"] / n / steps * 5.0,
        "seconds_per_round": st["seconds_per_round"],
        "central_seconds_per_window": central_s / steps,
        "max_position_gap_m": dp, "max_yaw_gap_deg": dth,
        "agents": agents,
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="sizes up to 16 only")
    parser.add_argument("--sizes", type=int, nargs="*", default=None, help="assembly counts (default 2..64)")
    parser.add_argument("--max-rounds", type=int, default=600, help="round cap per step")
    parser.add_argument("--out", default=str(Path(__file__).resolve().parent / "results" / "admm"))
    args = parser.parse_args(argv)
    sizes = args.sizes or ([2, 4, 8, 16] if args.quick else [2, 4, 8, 16, 32, 64])
    losses = [0.0, 0.1, 0.3, 0.5]
    steps_n = 3
    load0 = os.getloadavg()
    t0 = time.perf_counter()
    by_n = []
    for n in sizes:
        steps = steps_n if n <= 8 else (2 if n <= 16 else 1)
        r = one_run(n, steps, 0.0, max_rounds=args.max_rounds)
        by_n.append(r)
        print(f"n={n:3d} rounds/step={r['rounds_per_step']} msgs/agent/window={r['messages_per_agent_per_window']:.0f} "
              f"B/agent/s={r['bytes_per_agent_per_second_5hz']:.0f} s/round={r['seconds_per_round']:.3f} "
              f"gap={r['max_position_gap_m'] * 1e3:.3f} mm {r['max_yaw_gap_deg']:.4f} deg", flush=True)
    by_loss = []
    for loss in losses:
        r = one_run(4, steps_n, loss, max_rounds=3 * args.max_rounds)
        by_loss.append(r)
        print(f"loss={loss:.1f} rounds/step={r['rounds_per_step']} msgs/agent/window={r['messages_per_agent_per_window']:.0f} "
              f"converged={r['converged_all_steps']} gap={r['max_position_gap_m'] * 1e3:.3f} mm", flush=True)
    import numpy as _np
    import scipy
    result = {
        "benchmark": "admm",
        "machine": {"platform": platform.platform(), "python": platform.python_version(), "cpus": os.cpu_count(),
                    "loadavg_start": load0, "loadavg_end": os.getloadavg(),
                    "threads": {k: os.environ.get(k) for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS")}},
        "versions": {"numpy": _np.__version__, "scipy": scipy.__version__},
        "parameters": {"window": 5, "scenario_seed": 1, "steps_per_run": steps_n, "steps_per_run_n16": 2, "steps_per_run_above_16": 1, "max_rounds": args.max_rounds,
                       "round_period_s": 0.01, "frame_rate_hz": 5.0, "defaults": "AdmmRunConfig()"},
        "vs_assemblies": by_n,
        "vs_loss": by_loss,
        "target_16_assemblies_K5_rounds_le_100": next((max(r["rounds_per_step"]) <= 100 for r in by_n if r["n"] == 16), None),
        "ratio_seconds_per_round_to_central_window": [
            {"n": r["n"], "ratio": r["seconds_per_round"] / max(r["central_seconds_per_window"], 1e-12)} for r in by_n],
        "seconds": time.perf_counter() - t0,
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(out.with_suffix(".json"), result)
    _plot(result, out.with_suffix(".png"))
    print(f"wrote {out.with_suffix('.json')} and .png in {result['seconds']:.0f} s")
    return 0


def _plot(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 4, figsize=(18, 4))
    by_n, by_loss = result["vs_assemblies"], result["vs_loss"]
    ns = [r["n"] for r in by_n]
    ax[0].plot(ns, [max(r["rounds_per_step"]) for r in by_n], "o-", label="max rounds / step")
    ax[0].plot(ns, [r["rounds_last_step"] for r in by_n], "s--", label="rounds, last step")
    ax[0].set_xscale("log", base=2)
    ax[0].set_xlabel("assemblies")
    ax[0].set_ylabel("ADMM rounds to converge")
    ax[0].legend()
    ax[0].set_title("vs number of assemblies (loss 0)")
    losses = [r["loss"] for r in by_loss]
    ax[1].plot(losses, [np.mean(r["rounds_per_step"]) for r in by_loss], "o-", label="rounds / step")
    ax[1].plot(losses, [r["messages_per_agent_per_window"] for r in by_loss], "s--", label="ADMM msgs / agent / window")
    ax[1].set_xlabel("loss probability")
    ax[1].legend()
    ax[1].set_title("vs loss (4 assemblies)")
    for r in by_n:
        deg = [a["degree"] for a in r["agents"].values()]
        mpw = [a["messages_per_window"] for a in r["agents"].values()]
        ax[2].scatter(deg, mpw, s=12, label=f"n={r['n']}")
    ax[2].set_xlabel("agent degree (neighbours)")
    ax[2].set_ylabel("messages sent / window")
    ax[2].legend(fontsize=7)
    ax[2].set_title("messages per agent per window vs degree")
    ax[3].plot(ns, [r["bytes_per_agent_per_second_5hz"] / 1e3 for r in by_n], "o-", label="kB / agent / s at 5 Hz")
    ax[3].plot(ns, [r["seconds_per_round"] * 1e3 for r in by_n], "s--", label="wall ms / round (all agents)")
    ax[3].set_xscale("log", base=2)
    ax[3].set_yscale("log")
    ax[3].set_xlabel("assemblies")
    ax[3].legend()
    ax[3].set_title("traffic and wall time")
    fig.tight_layout()
    write_atomic(path, lambda fh: fig.savefig(fh, format="png", dpi=100), binary=True)
    plt.close(fig)


if __name__ == "__main__":
    raise SystemExit(main())
