"""Benchmark of the decentralized estimator (consensus-ADMM agents over the simulated network).

Fixed inputs: the ``multi`` ring (n <= 16) and ``ring64`` (n > 16) scenarios, scenario seed 1, K = 5,
the default ADMM and network parameters (round period 10 ms, latency 0.5 ms, jitter 1 ms), network
seed 1. Two ways to run the agents (``AdmmRunConfig.share_forms``):

* ``first`` (the default of ``decentral localize --mode admm``): the cold start shares the first
  step's pair forms (``admm.factors``) and every later window is plain consensus-ADMM, warm-started;
* ``every``: every window starts at the joint solution of the forms every agent broadcasts.

Measured per run: rounds per step, whether every step converged, the largest gap to the centralized
estimate (position, yaw) over all steps, messages per agent per window by kind and divided by the
agent's degree (neighbours in the view graph), bytes per agent per second at 5 Hz (one window per
0.2 s frame), wall and CPU time per round (all agents, one process), and the centralized estimator's
time per window on the same log in the same run (the reference).

Run ``OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python benchmarks/admm.py [--quick]``; writes
``benchmarks/results/admm.json`` and ``benchmarks/results/admm.png``.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from decentral.estimator import EstimatorConfig, estimate_log  # noqa: E402
from decentral.metrics import estimate_gap  # noqa: E402
from sims.admm_run import AdmmRunConfig, run_admm  # noqa: E402
from sims.io.atomic import write_atomic, write_json_atomic  # noqa: E402
from sims.scenarios import get_scenario, simulate  # noqa: E402

KINDS = {"admm": ("admm.primal", "admm.dual"), "forms": ("admm.factors",),
         "config": ("admm.config", "admm.config_request")}


def _gap(central, decentral):
    dp, dth, mismatched = estimate_gap(central, decentral)
    return dp, float(np.degrees(dth)), mismatched


def one_run(n: int, steps: int, loss: float, share: str, max_rounds: int, seed: int = 1) -> dict:
    """One decentralized run and its centralized reference on the same log."""
    scenario = get_scenario("multi" if n <= 16 else "ring64", n_assemblies=n, steps=steps)
    sim = simulate(scenario, seed=seed)
    t0, c0 = time.perf_counter(), time.process_time()
    central = estimate_log(sim.log, EstimatorConfig(window=5))
    central_wall, central_cpu = time.perf_counter() - t0, time.process_time() - c0
    load0 = os.getloadavg()
    c0 = time.process_time()
    run = run_admm(sim.log, config=AdmmRunConfig(window=5, loss=loss, max_rounds=max_rounds, share_forms=share),
                   seed=seed)
    cpu = time.process_time() - c0
    st = run.stats
    msgs = st["messages"]
    rounds = int(sum(run.rounds))
    agents = {}
    for name, a in st["agents"].items():
        sent = msgs["per_sender"].get(name, {})
        agents[name] = {"degree": len(a["neighbours"]), "messages_per_window": sent.get("sent", 0) / steps,
                        "bytes_per_second_5hz": sent.get("bytes_sent", 0) / steps * 5.0}
    by_kind = {group: sum(msgs["per_kind"].get(k, {}).get("sent", 0) for k in kinds) / n / steps
               for group, kinds in KINDS.items()}
    degree = np.array([a["degree"] for a in agents.values()], float)
    per_window = np.array([a["messages_per_window"] for a in agents.values()])
    ok = degree > 0
    dp, dth, mismatched = _gap(central, run.estimate)
    return {
        "n": n, "steps": steps, "loss": loss, "share_forms": share, "max_rounds": max_rounds,
        "rounds_per_step": list(run.rounds), "converged_per_step": list(run.converged),
        "converged_all_steps": bool(all(run.converged)),
        "messages_per_agent_per_window": float(per_window.mean()),
        "messages_per_agent_per_window_by_kind": by_kind,
        "messages_per_window_over_degree_median": float(np.median(per_window[ok] / degree[ok])) if ok.any() else None,
        "admm_messages_per_window_over_degree_median": (
            float(np.median(by_kind["admm"] / degree[ok])) if ok.any() else None),
        "degree_mean": float(degree.mean()),
        "bytes_per_agent_per_second_5hz": msgs["total"]["bytes_sent"] / n / steps * 5.0,
        "wall_seconds_per_round": st["seconds_per_round"],
        "cpu_seconds_per_round": cpu / max(rounds, 1),
        "central_wall_seconds_per_window": central_wall / steps,
        "central_cpu_seconds_per_window": central_cpu / steps,
        "max_position_gap_m": dp, "max_yaw_gap_deg": dth, "placement_mismatches": mismatched,
        "loadavg": [load0, os.getloadavg()],
        "agents": agents,
    }


def _print(r: dict) -> None:
    print(f"{r['share_forms']:5s} n={r['n']:3d} loss={r['loss']:.1f} rounds/step={r['rounds_per_step']} "
          f"conv={r['converged_all_steps']} msgs/agent/window={r['messages_per_agent_per_window']:.0f} "
          f"kB/agent/s={r['bytes_per_agent_per_second_5hz'] / 1e3:.1f} "
          f"ms/round wall {r['wall_seconds_per_round'] * 1e3:.1f} cpu {r['cpu_seconds_per_round'] * 1e3:.1f} "
          f"central ms/window {r['central_wall_seconds_per_window'] * 1e3:.1f} "
          f"gap {r['max_position_gap_m'] * 1e3:.3f} mm {r['max_yaw_gap_deg']:.4f} deg", flush=True)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="sizes up to 16 only")
    parser.add_argument("--sizes", type=int, nargs="*", default=None, help="assembly counts (default 2..64)")
    parser.add_argument("--max-rounds", type=int, default=400, help="round cap per step of plain ADMM (n <= 16)")
    parser.add_argument("--max-rounds-large", type=int, default=250, help="round cap per step of plain ADMM, n > 16")
    parser.add_argument("--out", default=str(Path(__file__).resolve().parent / "results" / "admm"))
    args = parser.parse_args(argv)
    sizes = args.sizes or ([2, 4, 8, 16] if args.quick else [2, 4, 8, 16, 32, 64])
    losses = [0.0, 0.1, 0.3, 0.5]
    load0 = os.getloadavg()
    t0, c0 = time.perf_counter(), time.process_time()
    by_n = []
    for share in ("every", "first"):
        for n in sizes:
            steps = 3 if (share == "every" or n <= 8) else 2
            cap = args.max_rounds if n <= 16 else args.max_rounds_large
            r = one_run(n, steps, 0.0, share, cap)
            by_n.append(r)
            _print(r)
    by_loss = []
    for share in ("every", "first"):
        for loss in losses:
            r = one_run(4, 3, loss, share, 3 * args.max_rounds)
            by_loss.append(r)
            _print(r)
    import scipy

    first16 = next((r for r in by_n if r["n"] == 16 and r["share_forms"] == "first"), None)
    every16 = next((r for r in by_n if r["n"] == 16 and r["share_forms"] == "every"), None)
    result = {
        "benchmark": "admm",
        "machine": {"platform": platform.platform(), "python": platform.python_version(), "cpus": os.cpu_count(),
                    "loadavg_start": load0, "loadavg_end": os.getloadavg(),
                    "threads": {k: os.environ.get(k) for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS")}},
        "versions": {"numpy": np.__version__, "scipy": scipy.__version__},
        "parameters": {"window": 5, "scenario_seed": 1, "network_seed": 1,
                       "steps": "3 (every; first with n <= 8), 2 (first with n >= 16)",
                       "max_rounds": {"n<=16": args.max_rounds, "n>16": args.max_rounds_large,
                                      "loss runs": 3 * args.max_rounds},
                       "loss_runs_assemblies": 4, "round_period_s": 0.01, "frame_rate_hz": 5.0,
                       "defaults": "AdmmRunConfig() apart from share_forms and max_rounds"},
        "vs_assemblies": by_n,
        "vs_loss": by_loss,
        "target_16_assemblies_K5_rounds_le_100": {
            "first (plain ADMM after the cold start)": None if first16 is None else bool(
                first16["converged_all_steps"] and max(first16["rounds_per_step"]) <= 100),
            "every (shared forms every window)": None if every16 is None else bool(
                every16["converged_all_steps"] and max(every16["rounds_per_step"]) <= 100)},
        "ratio_wall_seconds_per_round_to_central_window": [
            {"n": r["n"], "share_forms": r["share_forms"],
             "ratio": r["wall_seconds_per_round"] / max(r["central_wall_seconds_per_window"], 1e-12)} for r in by_n],
        "seconds": time.perf_counter() - t0,
        "cpu_seconds": time.process_time() - c0,
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(out.with_suffix(".json"), result)
    _plot(result, out.with_suffix(".png"))
    print(f"wrote {out.with_suffix('.json')} and .png in {result['seconds']:.0f} s ({result['cpu_seconds']:.0f} s CPU)")
    return 0


def _plot(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 4, figsize=(20, 4.3))
    styles = {"first": ("o-", "plain ADMM after the shared cold start"), "every": ("s--", "shared forms every window")}
    for share, (st, label) in styles.items():
        rows = [r for r in result["vs_assemblies"] if r["share_forms"] == share]
        if not rows:
            continue
        ns = [r["n"] for r in rows]
        warm = [max(r["rounds_per_step"][1:] or r["rounds_per_step"]) for r in rows]
        ax[0].plot(ns, warm, st, label=f"{share}: max rounds, later steps")
        ax[0].plot(ns, [r["rounds_per_step"][0] for r in rows], st, alpha=0.4, label=f"{share}: first step")
        for r, w in zip(rows, warm):
            if not r["converged_all_steps"]:
                ax[0].annotate("cap", (r["n"], w), textcoords="offset points", xytext=(3, 3), fontsize=7)
        ax[2].plot(ns, [r["messages_per_window_over_degree_median"] for r in rows], st,
                   label=f"{share}: all kinds")
        ax[2].plot(ns, [r["admm_messages_per_window_over_degree_median"] for r in rows], st, alpha=0.4,
                   label=f"{share}: admm.primal/dual only")
        ax[3].plot(ns, [r["bytes_per_agent_per_second_5hz"] / 1e3 for r in rows], st, label=f"{share}: kB/agent/s (5 Hz)")
        ax[3].plot(ns, [r["cpu_seconds_per_round"] * 1e3 for r in rows], st, alpha=0.4,
                   label=f"{share}: CPU ms/round (all agents)")
        lrows = [r for r in result["vs_loss"] if r["share_forms"] == share]
        ax[1].plot([r["loss"] for r in lrows], [np.mean(r["rounds_per_step"]) for r in lrows], st,
                   label=f"{share}: rounds/step")
        ax[1].plot([r["loss"] for r in lrows], [r["messages_per_agent_per_window"] for r in lrows], st, alpha=0.4,
                   label=f"{share}: msgs/agent/window")
    central = [r for r in result["vs_assemblies"] if r["share_forms"] == "every"]
    if central:
        ax[3].plot([r["n"] for r in central], [r["central_wall_seconds_per_window"] * 1e3 for r in central], "k:",
                   label="centralized ms/window (reference)")
    ax[0].axhline(100, color="grey", lw=0.8, ls=":")
    ax[0].set_xscale("log", base=2)
    ax[0].set_yscale("log")
    ax[0].set_xlabel("assemblies (ring)")
    ax[0].set_ylabel("ADMM rounds to converge")
    ax[0].set_title("rounds vs assemblies (loss 0; dotted: target 100)")
    ax[0].legend(fontsize=7)
    ax[1].set_xlabel("loss probability")
    ax[1].set_yscale("log")
    ax[1].set_title("vs loss (4 assemblies)")
    ax[1].legend(fontsize=7)
    ax[2].set_xscale("log", base=2)
    ax[2].set_yscale("log")
    ax[2].set_xlabel("assemblies (ring)")
    ax[2].set_ylabel("messages / agent / window / degree (median)")
    ax[2].set_title("messages per window per neighbour")
    ax[2].legend(fontsize=7)
    ax[3].set_xscale("log", base=2)
    ax[3].set_yscale("log")
    ax[3].set_xlabel("assemblies (ring)")
    ax[3].set_title("traffic and time")
    ax[3].legend(fontsize=7)
    fig.tight_layout()
    write_atomic(path, lambda fh: fig.savefig(fh, format="png", dpi=100), binary=True)
    plt.close(fig)


if __name__ == "__main__":
    raise SystemExit(main())
