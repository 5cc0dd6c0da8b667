"""Bytes on the wire of the decentralized estimator against a raw flood measured in the same run.

The reference (**raw flood**): every agent sends its own raw step data (its cameras' detections
``(id, u, v, r)`` and its odometry ``(dx, dy, dz, dtheta)``) to every other agent, one frame per agent
and step in the same framing as the protocol's frames: the message wire format plus the signed
envelope of the real transport (``98 + len(sender)`` bytes, :mod:`protocols.auth`). Both are computed
on the same log in the same run.

Measured, per ring size (``multi`` for n <= 16, ``ring64`` above, scenario seed 1, K = 5, no loss):

* **simulated network** (:func:`sims.runners.admm_run.run_admm`, the default agents): bytes per agent, every
  frame plus its envelope; ratio of the total to the flood's total, and of the busiest agent to its
  fair share of the flood (flood total / n), for the cold-start window (step 0) and the steady-state
  windows (later steps); frames per agent per steady window divided by its view-graph degree; the
  largest gap to the centralized estimate (the accuracy check);
* **real processes** (``decentral launch``, small rings): bytes counted by the socket transport at
  the senders (envelope included), same ratios, and the wall time from a sensor step to the agent's
  own end of the window (median over agents and steady windows), with 4, 8 and 16 processes, and
  the load average before and after each run (wall times depend on what else the machine runs).

Targets (steady state): total <= 1.0x the flood at 5 assemblies, <= 0.5x at 16, <= 0.25x at 64,
busiest agent within 3x its flood share, frames per agent per window growing no faster than its
degree.

Usage: ``python benchmarks/wire_budget.py [--out DIR] [--sizes 4 5 8 16 32 64] [--steps 8]
[--process-sizes 4 5 8] [--wall-sizes 4 8 16] [--round-period S] [--rounds-per-step 20] [--quick]``;
writes ``DIR/wire_budget.json`` and ``DIR/wire_budget.png`` (default ``out/benchmarks``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def build_parser() -> argparse.ArgumentParser:
    from _common import parser as common_parser

    parser = common_parser(__doc__)
    parser.add_argument("--sizes", type=int, nargs="*", default=[4, 5, 8, 16, 32, 64],
                        help="ring sizes on the simulated network")
    parser.add_argument("--steps", type=int, default=8, help="log steps per run (step 0 is the cold start)")
    parser.add_argument("--process-sizes", type=int, nargs="*", default=[4, 5, 8],
                        help="ring sizes also run as real processes (decentral launch)")
    parser.add_argument("--wall-sizes", type=int, nargs="*", default=[4, 8, 16],
                        help="ring sizes whose wall time per window is measured with real processes")
    parser.add_argument("--round-period", type=float, default=None,
                        help="processes: seconds per round (default 25 ms up to 8 processes, 25 ms x n / 8 above: "
                             "what a loaded 2-core machine sustains)")
    parser.add_argument("--rounds-per-step", type=int, default=20,
                        help="processes: rounds between two log steps; sets the rate (default 20)")
    parser.add_argument("--quick", action="store_true", help="sizes 4 5 8, 4 steps, processes 4 only")
    return parser


ENVELOPE = 98  # + len(sender): the signed envelope of protocols.auth


def _raw_message_class():
    from protocols.baselines.flood import RawStep

    return RawStep


def flood_bytes(log, raw_cls) -> "np.ndarray":
    """(steps, n) bytes each agent sends in the raw flood at each step (n - 1 copies, envelope included)."""
    import numpy as np

    names = list(log.assemblies)
    out = np.zeros((len(log.steps), len(names)))
    for k, step in enumerate(log.steps):
        for i, a in enumerate(names):
            dets = [d for key, ds in step.detections.items() if key.startswith(a + "/") for d in ds]
            odo = step.odometry.get(a)
            m = raw_cls(sender=a, receiver="*", round=k, t=step.t, ids=np.array([d.node for d in dets], np.int64),
                        uvr=np.array([[d.u, d.v, d.r] for d in dets]).reshape(-1, 3),
                        odometry=np.array([*odo.dp, odo.dtheta]) if odo is not None else np.zeros(0))
            out[k, i] = (m.size_bytes + ENVELOPE + len(a.encode())) * (len(names) - 1)
    return out


def _ring(n: int, steps: int):
    from sims.simulation.scenarios import get_scenario, simulate

    return simulate(get_scenario("multi" if n <= 16 else "ring64", n_assemblies=n, steps=steps), seed=1)


def _ratios(proto, flood, steps) -> dict:
    """Totals and busiest-agent ratios over the given steps (arrays are (steps, n))."""
    import numpy as np

    p, f = proto[steps].sum(axis=0), flood[steps].sum(axis=0)
    n = proto.shape[1]
    return {"bytes_total": float(p.sum()), "flood_total": float(f.sum()),
            "ratio_total": float(p.sum() / f.sum()),
            "busiest_vs_fair_share": float(p.max() / (f.sum() / n)),
            "bytes_per_agent_per_window_median": float(np.median(p) / max(1, len(steps)))}


def simulated(n: int, steps: int, raw_cls) -> dict:
    import time

    import numpy as np

    from sims.runners.admm_run import AdmmRunConfig, run_admm

    sim = _ring(n, steps)
    names = list(sim.log.assemblies)
    t0 = time.perf_counter()
    run = run_admm(sim.log, config=AdmmRunConfig(), seed=1)
    seconds = time.perf_counter() - t0
    over = np.array([len(a.encode()) + ENVELOPE for a in names])
    proto = np.array([np.sum([row for row in run.bytes_per_step[k].values()], axis=0)
                      + over * np.sum([row for row in run.messages_per_step[k].values()], axis=0)
                      if run.bytes_per_step[k] else np.zeros(len(names)) for k in range(steps)])
    frames = np.array([np.sum([row for row in run.messages_per_step[k].values()], axis=0)
                       if run.messages_per_step[k] else np.zeros(len(names)) for k in range(steps)])
    flood = flood_bytes(sim.log, raw_cls)
    degree = np.array([max(1, len(run.stats["agents"][a]["neighbours"])) for a in names])
    steady = list(range(1, steps))
    per_window = frames[steady].mean(axis=0) if steady else frames.mean(axis=0)
    by_kind = {}
    for k in steady:
        for kind, row in run.bytes_per_step[k].items():
            by_kind[kind] = by_kind.get(kind, 0) + int(np.sum(row))
    from decentral.estimator import EstimatorConfig, estimate_log
    from decentral.metrics import estimate_gap

    dp, dth, mismatched = estimate_gap(estimate_log(sim.log, EstimatorConfig(window=5)), run.estimate)
    return {"n": n, "steps": steps, "rounds_per_step": list(run.rounds), "converged": bool(all(run.converged)),
            "gap_to_centralized": {"position_m": float(dp), "yaw_deg": float(np.degrees(dth)),
                                   "steps_placing_differently": int(mismatched)},
            "seconds": seconds, "cold_start": _ratios(proto, flood, [0]), "steady": _ratios(proto, flood, steady),
            "steady_bytes_by_kind": by_kind,
            "frames_per_window": {"median": float(np.median(per_window)), "max": float(per_window.max())},
            "frames_per_neighbour": {"median": float(np.median(per_window / degree)),
                                     "max": float((per_window / degree).max())},
            "degree": {"median": float(np.median(degree)), "max": int(degree.max())}}


def pace(n: int, round_period: float | None, rounds_per_step: int, step_dt: float = 0.2) -> tuple[float, float]:
    """(rate, round period) of a run of ``n`` processes: ``rounds_per_step`` rounds per log step."""
    period = round_period or 0.025 * max(1.0, n / 8)
    return step_dt / (rounds_per_step * period), period


def processes(n: int, steps: int, raw_cls, rate: float, round_period: float) -> dict:
    import os
    import tempfile

    import numpy as np

    from sims.runners.launch import LaunchConfig, launch

    sim = _ring(n, steps)
    names = list(sim.log.assemblies)
    load = [list(os.getloadavg())]
    with tempfile.TemporaryDirectory() as tmp:
        result = launch(sim.log, LaunchConfig(rate=rate, round_period=round_period), workdir=tmp)
    load.append(list(os.getloadavg()))
    cum = np.zeros((steps, len(names)))
    windows = []
    for i, a in enumerate(names):
        for rec in (result.records[a][0] if result.records[a] else []):
            cum[rec["step"], i] = rec["counts"]["bytes"]
            if rec["step"] > 0 and rec.get("window_seconds") is not None:
                windows.append(rec["window_seconds"])
    proto = np.diff(np.vstack([np.zeros(len(names)), np.maximum.accumulate(cum, axis=0)]), axis=0)
    flood = flood_bytes(sim.log, raw_cls)
    steady = list(range(1, steps))
    return {"n": n, "steps": steps, "status": result.estimate.stats["status"],
            "converged_per_step": result.estimate.stats["converged_per_step"],
            "cold_start": _ratios(proto, flood, [0]), "steady": _ratios(proto, flood, steady),
            "window_seconds": {"median": float(np.median(windows)) if windows else None,
                               "max": float(np.max(windows)) if windows else None, "windows": len(windows)},
            "step_period_wall": float(np.median(np.diff([s.t for s in sim.log.steps]))) / rate,
            "rate": rate, "round_period": round_period, "loadavg": load}


def plot(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from _common import save_figure

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    sim = result["simulated"]
    ns = [r["n"] for r in sim]
    if sim:
        axes[0].plot(ns, [r["steady"]["ratio_total"] for r in sim], "o-", label="simulated: total / flood")
        axes[0].plot(ns, [r["steady"]["busiest_vs_fair_share"] for r in sim], "s--",
                     label="simulated: busiest / flood share")
    proc = result["processes"]
    if proc:
        axes[0].plot([r["n"] for r in proc], [r["steady"]["ratio_total"] for r in proc], "^", ms=9,
                     label="processes: total / flood")
    axes[0].plot([5, 16, 64], [1.0, 0.5, 0.25], "kx", ms=10, label="targets")
    axes[0].set_xscale("log", base=2)
    axes[0].set_yscale("log")
    axes[0].set_xlabel("assemblies (ring)")
    axes[0].set_ylabel("bytes, steady windows, relative to raw flood")
    axes[0].legend(fontsize=8)
    axes[1].plot(ns, [r["frames_per_neighbour"]["median"] for r in sim], "o-", label="median")
    axes[1].plot(ns, [r["frames_per_neighbour"]["max"] for r in sim], "s--", label="max")
    axes[1].set_xscale("log", base=2)
    axes[1].set_xlabel("assemblies (ring)")
    axes[1].set_ylabel("frames per agent per window / degree")
    axes[1].legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, path)


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    import json
    import os

    from _common import machine
    from sims.io.atomic import write_json_atomic

    if args.quick:
        args.sizes, args.steps, args.process_sizes, args.wall_sizes = [4, 5, 8], 4, [4], [4]
    raw_cls = _raw_message_class()
    out = {"machine": machine(), "parameters": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
           "simulated": [], "processes": [], "wall": []}
    for n in args.sizes:
        steps = args.steps if n <= 16 else min(args.steps, 5)
        row = simulated(n, steps, raw_cls)
        out["simulated"].append(row)
        print(f"sim n={n}: steady {row['steady']['ratio_total']:.3f}x flood, busiest "
              f"{row['steady']['busiest_vs_fair_share']:.2f}x share, cold start {row['cold_start']['ratio_total']:.2f}x, "
              f"frames/neighbour {row['frames_per_neighbour']['median']:.2f}, rounds {row['rounds_per_step']}, "
              f"gap {1000 * row['gap_to_centralized']['position_m']:.4f} mm", flush=True)
    for n in sorted(set(args.process_sizes) | set(args.wall_sizes)):
        row = processes(n, args.steps, raw_cls, *pace(n, args.round_period, args.rounds_per_step))
        if n in args.process_sizes:
            out["processes"].append(row)
        if n in args.wall_sizes:
            out["wall"].append({"processes": n, **row["window_seconds"], "step_period_wall": row["step_period_wall"],
                                "round_period": row["round_period"], "loadavg": row["loadavg"],
                                "converged_steps": sum(row["converged_per_step"]), "steps": row["steps"],
                                "converged_per_step": row["converged_per_step"],
                                "steady_bytes_over_flood": row["steady"]["ratio_total"]})
        print(f"processes n={n}: steady {row['steady']['ratio_total']:.3f}x flood, window "
              f"{row['window_seconds']['median']} s median", flush=True)
    targets = {5: 1.0, 16: 0.5, 64: 0.25}
    out["targets"] = {str(n): {"target": t, "measured": next((r["steady"]["ratio_total"] for r in out["simulated"]
                                                              if r["n"] == n), None)} for n, t in targets.items()}
    out["targets"]["busiest_within_3x"] = all(r["steady"]["busiest_vs_fair_share"] <= 3 for r in out["simulated"])
    out["machine"]["loadavg_end"] = list(os.getloadavg())
    args.out.mkdir(parents=True, exist_ok=True)
    write_json_atomic(args.out / "wire_budget.json", out)
    plot(out, args.out / "wire_budget.png")
    print(json.dumps(out["targets"], indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
