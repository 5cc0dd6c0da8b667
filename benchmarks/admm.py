"""Benchmark of the decentralized estimator (consensus-ADMM agents over the simulated network).

Fixed inputs: the ``multi`` ring (n <= 16) and ``ring64`` (n > 16) scenarios, scenario seed 1, K = 5,
the default ADMM and network parameters (round period 10 ms, latency 0.5 ms, jitter 1 ms), network
seed 1. Two ways to run the agents (``AdmmRunConfig.share_forms``):

* ``every`` (the default of ``decentral localize --mode admm``): every window starts at the joint
  solution of every agent's forms; once the agents know their routes to the reference (from the
  second window on) the newest step's forms travel up a spanning tree of the view graph
  (``admm.delta``) and the reference's joint solution comes back down (``admm.solution``;
  ``aggregation="tree"``, default); at the cold start the forms are broadcast. ``every/broadcast`` (``aggregation="broadcast"``,
  the earlier default) broadcasts them every window: the reference for the traffic;
* ``first``: the cold start shares the first step's forms and every later window is plain
  consensus-ADMM, warm-started.

Measured per run: rounds per step, whether every step converged, the largest gap to the centralized
estimate (position, yaw) over all steps, messages per agent per window by kind and divided by the
agent's degree (neighbours in the view graph), split into the cold-start window (step 0) and the
steady-state windows (later steps), median and max over agents, with a log-log fit of the
steady-state messages per neighbour against the number of assemblies (slope 0: flat), bytes per
agent per second at 5 Hz (one window per 0.2 s frame), wall and CPU time per round (all agents, one
process), and the centralized estimator's time per window on the same log in the same run (the
reference); the load average before and after each run (wall times depend on what else the machine
runs; CPU times much less).

Run ``OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python benchmarks/admm.py [--quick]``; writes
``OUT/admm.json`` and ``OUT/admm.png``.
"""

from __future__ import annotations

import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _common import output, parser, save_figure  # noqa: E402
from decentral.estimator import EstimatorConfig, estimate_log  # noqa: E402
from decentral.metrics import estimate_gap  # noqa: E402
from sims.runners.admm_run import AdmmRunConfig, run_admm  # noqa: E402
from sims.io.atomic import write_json_atomic  # noqa: E402
from sims.simulation.scenarios import get_scenario, simulate  # noqa: E402

KINDS = {"admm": ("admm.primal", "admm.dual"),
         "forms": ("admm.factors", "admm.factors_delta", "admm.bundle", "admm.bundle_ack", "admm.delta"),
         "solution": ("admm.solution",), "config": ("admm.config", "admm.config_request")}


def _windows(run, names: list[str], degree: np.ndarray, steps: list[int]) -> dict | None:
    """Messages per agent per window over the log steps ``steps``: by kind, and per neighbour (median, max)."""
    if not steps:
        return None
    per_step = [run.messages_per_step[k] for k in steps]
    kinds = sorted({kind for c in per_step for kind in c})
    by_kind = {kind: float(np.mean([np.mean(c.get(kind, [0] * len(names))) for c in per_step])) for kind in kinds}
    sent = np.mean([np.sum([row for row in c.values()], axis=0) if c else np.zeros(len(names)) for c in per_step],
                   axis=0)
    ok = degree > 0
    over = sent[ok] / degree[ok]
    return {"steps": steps, "messages_per_agent_per_window": float(sent.mean()),
            "messages_per_agent_per_window_max": float(sent.max()), "by_kind": by_kind,
            "over_degree_median": float(np.median(over)), "over_degree_max": float(over.max()),
            "broadcast_kinds_sent": bool(any(by_kind.get(k, 0) > 0 for k in ("admm.factors", "admm.factors_delta", "admm.config")))}


def _gap(central, decentral):
    dp, dth, mismatched = estimate_gap(central, decentral)
    return dp, float(np.degrees(dth)), mismatched


def one_run(n: int, steps: int, loss: float, share: str, max_rounds: int, seed: int = 1,
            aggregation: str = "tree") -> dict:
    """One decentralized run and its centralized reference on the same log."""
    scenario = get_scenario("multi" if n <= 16 else "ring64", n_assemblies=n, steps=steps)
    sim = simulate(scenario, seed=seed)
    t0, c0 = time.perf_counter(), time.process_time()
    central = estimate_log(sim.log, EstimatorConfig(window=5))
    central_wall, central_cpu = time.perf_counter() - t0, time.process_time() - c0
    load0 = os.getloadavg()
    c0 = time.process_time()
    run = run_admm(sim.log, config=AdmmRunConfig(window=5, loss=loss, max_rounds=max_rounds, share_forms=share,
                                                 aggregation=aggregation), seed=seed)
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
    names = list(st["agents"])
    return {
        "n": n, "steps": steps, "loss": loss, "share_forms": share, "aggregation": aggregation,
        "mode": share if share != "every" else f"every/{aggregation}", "max_rounds": max_rounds,
        "cold_start_window": _windows(run, names, degree, [0]),
        "steady_state_windows": _windows(run, names, degree, list(range(1, steps))),
        "tree_windows": int(sum(a["tree_windows"] for a in st["agents"].values())),
        "broadcast_windows": int(sum(a["broadcast_windows"] for a in st["agents"].values())),
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
    steady = r["steady_state_windows"]
    per_nb = "" if steady is None else (f"steady msgs/nbr med {steady['over_degree_median']:.2f} "
                                        f"max {steady['over_degree_max']:.2f} ")
    print(f"{r['mode']:15s} n={r['n']:3d} loss={r['loss']:.1f} rounds/step={r['rounds_per_step']} {per_nb}"
          f"conv={r['converged_all_steps']} msgs/agent/window={r['messages_per_agent_per_window']:.0f} "
          f"kB/agent/s={r['bytes_per_agent_per_second_5hz'] / 1e3:.1f} "
          f"ms/round wall {r['wall_seconds_per_round'] * 1e3:.1f} cpu {r['cpu_seconds_per_round'] * 1e3:.1f} "
          f"central ms/window {r['central_wall_seconds_per_window'] * 1e3:.1f} "
          f"gap {r['max_position_gap_m'] * 1e3:.3f} mm {r['max_yaw_gap_deg']:.4f} deg", flush=True)


MODES = (("every", "tree"), ("every", "broadcast"), ("first", "tree"))


def _flatness(rows: list[dict]) -> dict | None:
    """Log-log slope of steady-state messages per neighbour against n (0: flat), and the ratio largest/smallest n."""
    rows = [r for r in rows if r["steady_state_windows"] is not None]
    if len(rows) < 2:
        return None
    ns = np.array([r["n"] for r in rows], float)
    med = np.array([r["steady_state_windows"]["over_degree_median"] for r in rows])
    mx = np.array([r["steady_state_windows"]["over_degree_max"] for r in rows])
    big = ns >= 4  # n = 2: the one neighbour is both target and observer (two ADMM messages per round to it)
    return {"n": ns.astype(int).tolist(), "over_degree_median": med.tolist(), "over_degree_max": mx.tolist(),
            "loglog_slope_median": float(np.polyfit(np.log(ns), np.log(med), 1)[0]),
            "loglog_slope_max": float(np.polyfit(np.log(ns), np.log(mx), 1)[0]),
            "loglog_slope_median_n_ge_4": (float(np.polyfit(np.log(ns[big]), np.log(med[big]), 1)[0])
                                           if big.sum() >= 2 else None),
            "loglog_slope_max_n_ge_4": (float(np.polyfit(np.log(ns[big]), np.log(mx[big]), 1)[0])
                                        if big.sum() >= 2 else None),
            "ratio_median_largest_to_smallest_n": float(med[-1] / med[0]),
            "ratio_max_largest_to_smallest_n": float(mx[-1] / mx[0]),
            "max_over_degree_any_n": float(mx.max())}


def main(argv=None) -> int:
    ap = parser(__doc__)
    ap.add_argument("--quick", action="store_true", help="sizes up to 16 only")
    ap.add_argument("--sizes", type=int, nargs="*", default=None, help="assembly counts (default 2..64)")
    ap.add_argument("--steps", type=int, default=4, help="log steps of the shared-forms runs (1 cold + steady)")
    ap.add_argument("--max-rounds", type=int, default=400, help="round cap per step of plain ADMM (n <= 16)")
    ap.add_argument("--max-rounds-large", type=int, default=250, help="round cap per step of plain ADMM, n > 16")
    args = ap.parse_args(argv)
    sizes = args.sizes or ([2, 4, 8, 16] if args.quick else [2, 4, 8, 16, 32, 64])
    losses = [0.0, 0.1, 0.3, 0.5]
    load0 = os.getloadavg()
    t0, c0 = time.perf_counter(), time.process_time()
    by_n = []
    for share, aggregation in MODES:
        for n in sizes:
            steps = args.steps if share == "every" else (3 if n <= 8 else 2)
            cap = args.max_rounds if n <= 16 else args.max_rounds_large
            if share == "every":
                cap = 300  # the runner's default
            r = one_run(n, steps, 0.0, share, cap, aggregation=aggregation)
            by_n.append(r)
            _print(r)
    by_loss = []
    for share, aggregation in MODES:
        for loss in losses:
            r = one_run(4, args.steps if share == "every" else 3, loss, share, 3 * args.max_rounds,
                        aggregation=aggregation)
            by_loss.append(r)
            _print(r)
    import scipy

    def pick(mode, n):
        return next((r for r in by_n if r["n"] == n and r["mode"] == mode), None)

    first16, every16 = pick("first", 16), pick("every/tree", 16)
    result = {
        "benchmark": "admm",
        "machine": {"platform": platform.platform(), "python": platform.python_version(), "cpus": os.cpu_count(),
                    "loadavg_start": load0, "loadavg_end": os.getloadavg(),
                    "threads": {k: os.environ.get(k) for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS")}},
        "versions": {"numpy": np.__version__, "scipy": scipy.__version__},
        "parameters": {"window": 5, "scenario_seed": 1, "network_seed": 1,
                       "steps": f"{args.steps} (every: step 0 is the cold start, later steps the steady state); "
                                "first: 3 with n <= 8, 2 with n >= 16",
                       "max_rounds": {"every": 300, "first, n<=16": args.max_rounds, "first, n>16": args.max_rounds_large,
                                      "loss runs": 3 * args.max_rounds},
                       "loss_runs_assemblies": 4, "round_period_s": 0.01, "frame_rate_hz": 5.0,
                       "defaults": "AdmmRunConfig() apart from share_forms, aggregation and max_rounds"},
        "vs_assemblies": by_n,
        "vs_loss": by_loss,
        "steady_state_messages_per_neighbour_vs_n": {
            mode: _flatness([r for r in by_n if r["mode"] == mode]) for mode in ("every/tree", "every/broadcast")},
        "target_16_assemblies_K5_rounds_le_100": {
            "first (plain ADMM after the cold start)": None if first16 is None else bool(
                first16["converged_all_steps"] and max(first16["rounds_per_step"]) <= 100),
            "every (shared forms every window, tree)": None if every16 is None else bool(
                every16["converged_all_steps"] and max(every16["rounds_per_step"]) <= 100)},
        "ratio_wall_seconds_per_round_to_central_window": [
            {"n": r["n"], "mode": r["mode"],
             "ratio": r["wall_seconds_per_round"] / max(r["central_wall_seconds_per_window"], 1e-12)} for r in by_n],
        "seconds": time.perf_counter() - t0,
        "cpu_seconds": time.process_time() - c0,
    }
    out = output(args.out, "admm", "")
    write_json_atomic(out.with_suffix(".json"), result)
    _plot(result, out.with_suffix(".png"))
    for mode, fit in result["steady_state_messages_per_neighbour_vs_n"].items():
        if fit:
            print(f"{mode}: steady msgs/neighbour median {['%.2f' % v for v in fit['over_degree_median']]} "
                  f"max {['%.2f' % v for v in fit['over_degree_max']]} slope {fit['loglog_slope_median']:.3f}")
    print(f"wrote {out.with_suffix('.json')} and .png in {result['seconds']:.0f} s ({result['cpu_seconds']:.0f} s CPU)")
    return 0


def _plot(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 4, figsize=(21, 4.5))
    styles = {"every/tree": ("s-", "C0"), "every/broadcast": ("^--", "C1"), "first": ("o:", "C2")}
    for mode, (st, color) in styles.items():
        rows = [r for r in result["vs_assemblies"] if r["mode"] == mode]
        if not rows:
            continue
        ns = [r["n"] for r in rows]
        warm = [max(r["rounds_per_step"][1:] or r["rounds_per_step"]) for r in rows]
        ax[0].plot(ns, warm, st, color=color, label=f"{mode}: max rounds, later steps")
        ax[0].plot(ns, [r["rounds_per_step"][0] for r in rows], st, color=color, alpha=0.35,
                   label=f"{mode}: first step")
        for r, w in zip(rows, warm):
            if not r["converged_all_steps"]:
                ax[0].annotate("cap", (r["n"], w), textcoords="offset points", xytext=(3, 3), fontsize=7)
        steady = [r["steady_state_windows"] for r in rows]
        ax[2].plot(ns, [w["over_degree_median"] for w in steady], st, color=color, label=f"{mode}: steady, median")
        ax[2].plot(ns, [w["over_degree_max"] for w in steady], st, color=color, alpha=0.5, lw=0.8,
                   label=f"{mode}: steady, max over agents")
        if mode == "every/tree":
            ax[2].plot(ns, [r["cold_start_window"]["over_degree_median"] for r in rows], "x:", color="grey",
                       label="cold start (step 0, broadcast), median")
        ax[3].plot(ns, [r["bytes_per_agent_per_second_5hz"] / 1e3 for r in rows], st, color=color,
                   label=f"{mode}: kB/agent/s (5 Hz)")
        ax[3].plot(ns, [r["cpu_seconds_per_round"] * 1e3 for r in rows], st, color=color, alpha=0.35,
                   label=f"{mode}: CPU ms/round (all agents)")
        lrows = [r for r in result["vs_loss"] if r["mode"] == mode]
        ax[1].plot([r["loss"] for r in lrows], [np.mean(r["rounds_per_step"]) for r in lrows], st, color=color,
                   label=f"{mode}: rounds/step")
        ax[1].plot([r["loss"] for r in lrows], [r["messages_per_agent_per_window"] for r in lrows], st, color=color,
                   alpha=0.35, label=f"{mode}: msgs/agent/window")
    central = [r for r in result["vs_assemblies"] if r["mode"] == "every/tree"]
    if central:
        ax[3].plot([r["n"] for r in central], [r["central_wall_seconds_per_window"] * 1e3 for r in central], "k:",
                   label="centralized ms/window (reference)")
    ax[0].axhline(100, color="grey", lw=0.8, ls=":")
    panels = [  # (x label, y label, title); every panel but the loss one has n on a log2 axis
        ("assemblies (ring)", "ADMM rounds to converge", "rounds vs assemblies (loss 0; dotted: target 100)"),
        ("loss probability", None, "vs loss (4 assemblies)"),
        ("assemblies (ring)", "messages / agent / window / degree", "messages per window per neighbour (loss 0)"),
        ("assemblies (ring)", None, "traffic and time"),
    ]
    for a, (xlabel, ylabel, title) in zip(ax, panels):
        if xlabel.startswith("assemblies"):
            a.set_xscale("log", base=2)
        a.set_yscale("log")
        a.set_xlabel(xlabel)
        if ylabel:
            a.set_ylabel(ylabel)
        a.set_title(title)
        a.legend(fontsize=6)
    fig.tight_layout()
    save_figure(fig, path, dpi=100)


if __name__ == "__main__":
    raise SystemExit(main())
