"""Agents in the field: rings as real processes in network namespaces, under delay, jitter, loss and CPU load.

For every cell of the matrix (ring size x transport x one-way delay x packet loss x busy processes per
core) the log runs as one ``decentral agent`` per namespace behind impaired links
(:mod:`sims.lab.field`), and the reference agent's estimate is compared with the centralized estimate of
the same log, computed in the same run. Per cell: share of the centralized estimate's placements
that the agents placed (on time, and at most one sensor step late), the position / yaw gap of the
converged steps (those converged without the forms of an agent given up on as down, ``converged_without``,
apart) and of all placed steps, steps converged, rounds and bytes per window, frame
latency (sender's clock to arrival: median, p90, max over windows; a TCP stall after a lost packet
shows here), how late the processes ran their rounds against their own clocks and their CPU per step
(a starved CPU shows there), ``stats.status``, and the simulated runner's prediction of the convergence share at
the same latency (:func:`sims.runners.admm_run.run_admm` with the links' latency and jitter and the same
round budget). Needs Linux and root (``ip netns``; ``iptables`` for loss).

Usage: ``python benchmarks/field.py [--out DIR] [--sizes 5 8] [--transports udp zmq] [--delays 0 0.01
0.05 0.2] [--losses 0 0.1] [--busy 0 2] [--parity-groups 4 0] [--repeats R] [--steps 12] [--rate 0.4]
[--round-period 0.025] [--aggregations tree broadcast] [--keep-failed DIR]`` (``--quick``: one small cell per
transport; ``--keep-failed``: the folders of the runs that did not place everything or timed out, to read their
streams);
``--aggregations``: how a window's forms travel (``decentral agent --aggregation``), each a cell of its own.
``--parity-groups``: the UDP
transport's data datagrams per parity datagram (``decentral agent --parity-group``; 0: none), each a
cell of its own; ``--repeats``: each cell again with the next link and agent seeds (a shared machine's
load moves these figures by tens of points from run to run), summarized per cell in ``summary``
(median and range over the repeats). Writes ``field.json`` and ``field.png``.
"""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
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
    ap.add_argument("--parity-groups", type=int, nargs="+", default=[4],
                    help="udp: data datagrams per parity datagram, each a cell (0: none; default 4)")
    ap.add_argument("--aggregations", nargs="+", default=["tree"], choices=("tree", "broadcast"),
                    help="how a window's forms travel, each a cell (default: tree)")
    ap.add_argument("--repeats", type=int, default=1, help="runs of each cell, seeds SEED, SEED+1, ...")
    ap.add_argument("--steps", type=int, default=12)
    ap.add_argument("--rate", type=float, default=0.4, help="log seconds per wall second")
    ap.add_argument("--round-period", type=float, default=0.025)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--quick", action="store_true", help="one 4-ring cell per transport (30 ms, 20 %% loss)")
    ap.add_argument("--keep-failed", type=Path, metavar="DIR",
                    help="keep the folder of every run that placed less than the centralized estimator on time or "
                         "timed out (the agents' streams, stderr, parts and throw-away keys) under DIR, one subfolder "
                         "per run")
    ap.add_argument("--force", action="store_true", help="overwrite an existing field.json in --out")
    return ap


def _cell_metrics(central, est, records, reference):
    import numpy as np

    stats = est.stats
    steps = len(central.steps)
    want = placed = placed_late = 0
    gaps_conv, gaps_all, yaw_conv, gaps_without = [], [], [], []
    # converged without the forms of agents given up on as down: the others' data only (compared apart)
    without = {e["step"] for e in stats.get("converged_without", [])}
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
            if stats["converged_per_step"][k] and k in without:
                gaps_without.append(dp)
            elif stats["converged_per_step"][k]:
                gaps_conv.append(dp)
                yaw_conv.append(dy)
    lat = [r["latency_ms"] for run in records.get(reference, []) for r in run if r.get("latency_ms")]
    q = lambda xs, p: float(np.quantile(xs, p)) if xs else None  # noqa: E731
    windows = max(1, sum(len(run) for runs in records.values() for run in runs))
    # windows the agents shared by broadcast (the cold start, slow links, a process running late), of all shared
    # (an agent's counters are cumulative: its last record that has them; a revised step's line has none)
    ends = [next((r["counters"] for r in reversed(run) if "counters" in r), {}) for runs in records.values() for run in runs]
    shared = sum(c.get("tree_windows", 0) + c.get("broadcast_windows", 0) for c in ends)
    return {
        "placed_share": placed / want if want else 1.0,
        "placed_share_one_step_late": placed_late / want if want else 1.0,
        "converged_steps": int(sum(stats["converged_per_step"])), "steps": steps,
        "gap_converged_mm": {"max": 1e3 * max(gaps_conv, default=0.0), "median": 1e3 * q(gaps_conv, 0.5) if gaps_conv else None},
        "converged_without_steps": len(without),
        "gap_converged_without_mm": 1e3 * max(gaps_without, default=0.0),
        "yaw_gap_converged_deg": float(np.degrees(max(yaw_conv, default=0.0))),
        "gap_placed_mm": {"max": 1e3 * max(gaps_all, default=0.0), "median": 1e3 * q(gaps_all, 0.5) if gaps_all else None},
        "rounds_per_window": {"median": q(stats["rounds_per_step"], 0.5)},
        "bytes_per_window": stats["bytes"]["total"] / windows,
        "broadcast_share": sum(c.get("broadcast_windows", 0) for c in ends) / shared if shared else None,
        "frame_latency_ms": {"median_of_medians": q([x[0] for x in lat], 0.5), "p90_of_p90s": q([x[1] for x in lat], 0.9),
                             "max": max((x[2] for x in lat), default=None)},
        # the processes' own clocks: how late they ran their half rounds (worst agent's median step p90) and
        # their CPU per step (largest agent median): a starved CPU, told apart from the links
        "behind_ms_p90": max((v[0] for v in stats.get("behind_ms", {}).values()), default=None),
        "cpu_ms_per_step": max((v[0] for v in stats.get("cpu_ms", {}).values()), default=None),
        "status": stats["status"], "status_counts": stats["status_counts"],
    }


def _simulated(log, central, delay, jitter, loss, budget, round_period, seed, transport, aggregation="tree"):
    """The simulated runner at the same latency, jitter, loss and round budget: its convergence share.

    Over UDP the loss is per datagram, as the field's relays lose datagrams (``AdmmRunConfig.mtu``)."""
    from sims.runners.admm_run import AdmmRunConfig, run_admm

    cfg = AdmmRunConfig(window=5, loss=loss, latency=delay * (1 - jitter), jitter=2 * jitter * delay,
                        round_period=round_period, max_rounds=budget, fast_forward=False,
                        mtu=1200 if transport == "udp" else 0, aggregation=aggregation)
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
    # repeats outermost: the machine's load drifts, and each repeat meets every cell at about the same load
    cells = [(n, tr, par, agg, d, loss, busy, args.seed + r) for r in range(args.repeats) for n in args.sizes
             for tr in args.transports for par in (args.parity_groups if tr == "udp" else [None])
             for agg in args.aggregations for d in args.delays for loss in args.losses for busy in args.busy]
    if args.quick:
        args.steps = 8
        cells = [(4, tr, 4 if tr == "udp" else None, "tree", 0.03, 0.2, 0, args.seed) for tr in args.transports]
    payload = {"benchmark": "field", "machine": machine(),
               "parameters": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()}, "cells": []}
    logs = {}
    for n, tr, parity, agg, delay, loss, busy, seed in cells:
        if n not in logs:
            sim = simulate(get_scenario("multi", n_assemblies=n, steps=args.steps), seed=args.seed)
            t0 = time.perf_counter()
            central = estimate_log(sim.log, EstimatorConfig(window=5))
            logs[n] = (sim.log, central, time.perf_counter() - t0)
        log, central, central_s = logs[n]
        load = os.getloadavg()[0]
        t0 = time.perf_counter()
        extra = ("--parity-group", str(parity)) if parity is not None else ()
        with tempfile.TemporaryDirectory(prefix="decentral-field-") as work:
            result = run_field(log, LaunchConfig(rate=args.rate, round_period=args.round_period, transport=tr,
                                                 seed=seed, aggregation=agg, extra_args=extra),
                               FieldConfig(delay=delay, jitter=args.jitter, loss=loss, busy_per_core=busy, seed=seed),
                               workdir=work)
            wall = time.perf_counter() - t0
            row = {"n": n, "transport": tr, "parity_group": parity, "aggregation": agg, "delay": delay, "loss": loss,
                   "busy_per_core": busy, "seed": seed, "loadavg_before": load,
                   "wall_seconds": wall, "centralized_seconds": central_s, "timed_out": result.timed_out,
                   **_cell_metrics(central, result.estimate, result.records, log.assemblies[0])}
            if args.keep_failed is not None and (row["placed_share"] < 1.0 or result.timed_out):
                kept = args.keep_failed / f"n{n}_{tr}_{agg}_delay{delay:g}_loss{loss:g}_busy{busy}_seed{seed}"
                shutil.copytree(work, kept, dirs_exist_ok=True)
                row["kept"] = str(kept)
        budget = rounds_per_step(log, args.rate, args.round_period)
        row["simulated"] = _simulated(log, central, delay, args.jitter, loss, budget, args.round_period, seed, tr, agg)
        payload["cells"].append(row)
        print(f"n={n} {tr}{'' if parity is None else f' parity {parity}'} {agg} seed {seed} delay={delay * 1e3:.0f}ms loss={loss:.0%} busy={busy}: placed {row['placed_share']:.0%} "
              f"(+1 step {row['placed_share_one_step_late']:.0%}), converged {row['converged_steps']}/{row['steps']} "
              f"(sim {row['simulated']['converged_steps']}), max gap conv {row['gap_converged_mm']['max']:.2f} mm, "
              f"latency p90 {row['frame_latency_ms']['p90_of_p90s']} ms, rounds behind p90 {row['behind_ms_p90']} ms, "
              f"CPU/step {row['cpu_ms_per_step']} ms, broadcast {row['broadcast_share'] or 0:.0%} of windows, "
              f"{row['status']}, load {load:.1f}",
              file=sys.stderr, flush=True)
    payload["summary"] = summarize(payload["cells"])
    save("field", payload, args.out)
    plot(payload, output(args.out, "field", ".png"), save_figure)
    return 0


_CELL = ("n", "transport", "parity_group", "aggregation", "delay", "loss", "busy_per_core")


def summarize(cells: list[dict]) -> list[dict]:
    """Per cell (all but the seed): median, least and most over its repeats of the placement shares, steps
    converged, bytes per agent and window and the share of windows shared by broadcast, and the largest gap of a converged step to the centralized estimate."""
    import numpy as np

    out = []
    for key in sorted({tuple(c[k] for k in _CELL) for c in cells}, key=str):
        rows = [c for c in cells if tuple(c[k] for k in _CELL) == key]
        stat = lambda xs: {"median": float(np.median(xs)), "min": float(min(xs)), "max": float(max(xs))}  # noqa: E731
        out.append({**dict(zip(_CELL, key)), "repeats": len(rows),
                    "placed_share": stat([c["placed_share"] for c in rows]),
                    "placed_share_one_step_late": stat([c["placed_share_one_step_late"] for c in rows]),
                    "converged_steps": stat([c["converged_steps"] for c in rows]),
                    "bytes_per_window": stat([c["bytes_per_window"] for c in rows]),
                    "broadcast_share": stat(shares) if (shares := [c["broadcast_share"] for c in rows
                                                                  if c.get("broadcast_share") is not None]) else None,
                    "gap_converged_mm_max": max(c["gap_converged_mm"]["max"] for c in rows),
                    "converged_without_steps": sum(c.get("converged_without_steps", 0) for c in rows)})
    return out


def plot(payload: dict, path: Path, save_figure) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    import numpy as np

    cells = payload["cells"]
    fig, axes = plt.subplots(1, 4, figsize=(17, 3.8))
    line = ("n", "transport", "parity_group", "loss", "busy_per_core", "aggregation")
    for key in sorted({tuple(c[k] for k in line) for c in cells}, key=str):
        rows = [c for c in cells if tuple(c[k] for k in line) == key]
        delays = sorted({c["delay"] for c in rows})
        med = lambda f: [float(np.median([f(c) for c in rows if c["delay"] == d])) for d in delays]  # noqa: E731
        x = [1e3 * d for d in delays]
        label = (f"n={key[0]} {key[1]}{'' if key[2] is None else f' parity {key[2]}'} loss {key[3]:.0%} "
                 f"busy {key[4]}{' broadcast' if key[5] == 'broadcast' else ''}")
        style = ("-" if key[1] == "udp" else "--") if key[5] == "tree" else ":"
        axes[0].plot(x, med(lambda c: c["placed_share"]), style, marker="o", label=label)
        axes[1].plot(x, med(lambda c: c["converged_steps"] / c["steps"]), style, marker="o")
        axes[2].plot(x, med(lambda c: c["bytes_per_window"] / 1e3), style, marker="o")
        axes[3].plot(x, med(lambda c: c["frame_latency_ms"]["p90_of_p90s"] or 0), style, marker="o")
    for ax, title in zip(axes, ("placed / centralized's placements (median of repeats)", "steps converged (share)",
                                "kB per agent and window", "frame latency p90 [ms]")):
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
