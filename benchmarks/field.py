"""Agents in the field: rings as real processes in network namespaces, under delay, jitter, loss and CPU load.

For every cell of the matrix (ring size x transport x one-way delay x packet loss x busy processes per
core) the log runs as one ``decentral agent`` per namespace behind impaired links
(:mod:`sims.lab.field`), and the reference agent's estimate is compared with the centralized estimate of
the same log, computed in the same run. Per cell: share of the centralized estimate's placements
that the agents placed (on time, and at most one sensor step late), the position / yaw gap of the
converged steps and of all placed steps, steps converged, rounds and bytes per window, frame
latency (sender's clock to arrival: median, p90, max over windows; a TCP stall after a lost packet
shows here), ``stats.status``, and the simulated runner's prediction of the convergence share at
the same latency (:func:`sims.runners.admm_run.run_admm` with the links' latency and jitter and the same
round budget). Needs Linux and root (``ip netns``; ``iptables`` for loss).

Usage: ``python benchmarks/field.py [--out DIR] [--sizes 5 8] [--transports udp zmq] [--delays 0 0.01
0.05 0.2] [--losses 0 0.1] [--busy 0 2] [--steps 12] [--rate 0.4] [--round-period 0.025]``
(``--quick``: one small cell per transport). Writes ``field.json`` and ``field.png``.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))


def build_parser():
    from _common import parser

    ap = parser(__doc__)
    ap.add_argument("--sizes", type=int, nargs="+", default=[5, 8])
    ap.add_argument("--transports", nargs="+", default=["udp", "zmq"], choices=("udp", "zmq"))
    ap.add_argument("--delays", type=float, nargs="+", default=[0.0, 0.01, 0.05, 0.2], help="one-way delay (s)")
    ap.add_argument("--jitter", type=float, default=0.2, help="relative jitter of the delay (default 0.2)")
    ap.add_argument("--losses", type=float, nargs="+", default=[0.0, 0.1])
    ap.add_argument("--busy", type=int, nargs="+", default=[0, 2], help="busy processes per core")
    ap.add_argument("--steps", type=int, default=12)
    ap.add_argument("--rate", type=float, default=0.4, help="log seconds per wall second")
    ap.add_argument("--round-period", type=float, default=0.025)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--quick", action="store_true", help="one 4-ring cell per transport (30 ms, 20 %% loss)")
    ap.add_argument("--force", action="store_true", help="overwrite an existing field.json in --out")
    return ap


def _cell_metrics(central, est, records, reference):
    import numpy as np

    stats = est.stats
    steps = len(central.steps)
    want = placed = placed_late = 0
    gaps_conv, gaps_all, yaw_conv = [], [], []
    for k in range(steps):
        c, e = central.steps[k], est.steps[k]
        want += len(c.poses)
        here = [a for a in c.poses if a in e.poses]
        placed += len(here)
        late = set(here) | (set(est.steps[k + 1].poses) if k + 1 < steps else set())
        placed_late += len([a for a in c.poses if a in late])
        for a in here:
            dp = float(np.linalg.norm(c.poses[a].p - e.poses[a].p))
            dy = float(abs(np.angle(np.exp(1j * (c.poses[a].theta - e.poses[a].theta)))))
            gaps_all.append(dp)
            if stats["converged_per_step"][k]:
                gaps_conv.append(dp)
                yaw_conv.append(dy)
    lat = [r["latency_ms"] for run in records.get(reference, []) for r in run if r.get("latency_ms")]
    q = lambda xs, p: float(np.quantile(xs, p)) if xs else None  # noqa: E731
    windows = max(1, sum(len(run) for runs in records.values() for run in runs))
    return {
        "placed_share": placed / want if want else 1.0,
        "placed_share_one_step_late": placed_late / want if want else 1.0,
        "converged_steps": int(sum(stats["converged_per_step"])), "steps": steps,
        "gap_converged_mm": {"max": 1e3 * max(gaps_conv, default=0.0), "median": 1e3 * q(gaps_conv, 0.5) if gaps_conv else None},
        "yaw_gap_converged_deg": float(np.degrees(max(yaw_conv, default=0.0))),
        "gap_placed_mm": {"max": 1e3 * max(gaps_all, default=0.0), "median": 1e3 * q(gaps_all, 0.5) if gaps_all else None},
        "rounds_per_window": {"median": q(stats["rounds_per_step"], 0.5)},
        "bytes_per_window": stats["bytes"]["total"] / windows,
        "frame_latency_ms": {"median_of_medians": q([x[0] for x in lat], 0.5), "p90_of_p90s": q([x[1] for x in lat], 0.9),
                             "max": max((x[2] for x in lat), default=None)},
        "status": stats["status"], "status_counts": stats["status_counts"],
    }


def _simulated(log, central, delay, jitter, loss, budget, round_period, seed):
    """The simulated runner at the same latency, jitter, loss and round budget: its convergence share."""
    from sims.runners.admm_run import AdmmRunConfig, run_admm

    cfg = AdmmRunConfig(window=5, loss=loss, latency=delay * (1 - jitter), jitter=2 * jitter * delay,
                        round_period=round_period, max_rounds=budget, fast_forward=False)
    run = run_admm(log, config=cfg, seed=seed)
    return {"converged_steps": int(sum(run.converged)), "status": run.stats["status"]}


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    from _common import machine, output, save, save_figure

    from decentral.estimator import EstimatorConfig, estimate_log
    from sims.runners.agent_run import rounds_per_step
    from sims.lab.field.netns import available
    from sims.lab.field.run import FieldConfig, run_field
    from sims.runners.launch import LaunchConfig
    from sims.simulation.scenarios import get_scenario, simulate

    why = available()
    if why:
        print(f"field.py: {why}", file=sys.stderr)
        return 2
    path = output(args.out, "field")
    if path.exists() and not args.force:
        print(f"field.py: {path} exists (give --force to replace it)", file=sys.stderr)
        return 2
    cells = [(n, tr, d, loss, busy) for n in args.sizes for tr in args.transports for d in args.delays
             for loss in args.losses for busy in args.busy]
    if args.quick:
        args.steps = 8
        cells = [(4, tr, 0.03, 0.2, 0) for tr in args.transports]
    payload = {"benchmark": "field", "machine": machine(),
               "parameters": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()}, "cells": []}
    logs = {}
    for n, tr, delay, loss, busy in cells:
        if n not in logs:
            sim = simulate(get_scenario("multi", n_assemblies=n, steps=args.steps), seed=args.seed)
            t0 = time.perf_counter()
            central = estimate_log(sim.log, EstimatorConfig(window=5))
            logs[n] = (sim.log, central, time.perf_counter() - t0)
        log, central, central_s = logs[n]
        load = os.getloadavg()[0]
        t0 = time.perf_counter()
        result = run_field(log, LaunchConfig(rate=args.rate, round_period=args.round_period, transport=tr,
                                             seed=args.seed),
                           FieldConfig(delay=delay, jitter=args.jitter, loss=loss, busy_per_core=busy, seed=args.seed))
        wall = time.perf_counter() - t0
        row = {"n": n, "transport": tr, "delay": delay, "loss": loss, "busy_per_core": busy, "loadavg_before": load,
               "wall_seconds": wall, "centralized_seconds": central_s, "timed_out": result.timed_out,
               **_cell_metrics(central, result.estimate, result.records, log.assemblies[0])}
        budget = rounds_per_step(log, args.rate, args.round_period)
        row["simulated"] = _simulated(log, central, delay, args.jitter, loss, budget, args.round_period, args.seed)
        payload["cells"].append(row)
        print(f"n={n} {tr} delay={delay * 1e3:.0f}ms loss={loss:.0%} busy={busy}: placed {row['placed_share']:.0%} "
              f"(+1 step {row['placed_share_one_step_late']:.0%}), converged {row['converged_steps']}/{row['steps']} "
              f"(sim {row['simulated']['converged_steps']}), max gap conv {row['gap_converged_mm']['max']:.2f} mm, "
              f"latency p90 {row['frame_latency_ms']['p90_of_p90s']} ms, {row['status']}, load {load:.1f}",
              file=sys.stderr, flush=True)
    save("field", payload, args.out)
    plot(payload, output(args.out, "field", ".png"), save_figure)
    return 0


def plot(payload: dict, path: Path, save_figure) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cells = payload["cells"]
    fig, axes = plt.subplots(1, 4, figsize=(17, 3.8))
    keys = sorted({(c["n"], c["transport"], c["loss"], c["busy_per_core"]) for c in cells})
    for key in keys:
        rows = sorted((c for c in cells if (c["n"], c["transport"], c["loss"], c["busy_per_core"]) == key),
                      key=lambda c: c["delay"])
        x = [1e3 * c["delay"] for c in rows]
        label = f"n={key[0]} {key[1]} loss {key[2]:.0%} busy {key[3]}"
        style = "-" if key[1] == "udp" else "--"
        axes[0].plot(x, [c["placed_share"] for c in rows], style, marker="o", label=label)
        axes[1].plot(x, [c["converged_steps"] / c["steps"] for c in rows], style, marker="o")
        axes[2].plot(x, [c["bytes_per_window"] / 1e3 for c in rows], style, marker="o")
        axes[3].plot(x, [c["frame_latency_ms"]["p90_of_p90s"] or 0 for c in rows], style, marker="o")
    for ax, title in zip(axes, ("placed / centralized's placements", "steps converged (share)",
                                "kB per window (all agents)", "frame latency p90 [ms]")):
        ax.set_xlabel("one-way delay [ms]")
        ax.set_title(title, fontsize=9)
        ax.grid(alpha=0.3)
    axes[3].set_yscale("symlog")
    axes[0].legend(fontsize=6)
    m = payload["machine"]
    fig.suptitle(f"field: rings as processes in namespaces (load {m['loadavg_start'][0]:.1f}-{m['loadavg_end'][0]:.1f}, "
                 f"{m['cpus']} cpus)", fontsize=9)
    fig.tight_layout()
    save_figure(fig, path)


if __name__ == "__main__":
    sys.exit(main())
