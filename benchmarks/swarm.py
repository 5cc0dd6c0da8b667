"""Kanovsky's swarm: on-board EKF accuracy and radio traffic vs message loss.

Fixed inputs: 6 robots in a 5 m arena, 150 steps at 5 Hz (30 s), wander policy, seeds 0-4, radio
with 5 ms latency and 10 ms jitter, i.i.d. loss in {0, 10, 30, 50} % plus 5 % duplication when lossy.
Per loss rate: median position and yaw error of every robot's estimate of every other robot (pooled
over steps, pairs and seeds), fraction of pairs tracked and with known yaw at the end, mean NEES of
yaw-known tracks (3 = consistent), messages and bytes sent per robot per second, wall time per step.
Ratios are against the lossless run measured in the same program. Single core.

Usage: ``python benchmarks/swarm.py [--quick]``; writes ``OUT/swarm.json`` and
``swarm.png`` (plotted from the saved JSON).
"""

from __future__ import annotations

import json
import time
from dataclasses import replace

from _common import machine, output, parser, save, save_figure  # noqa: I001  (pins threads before numpy)

import numpy as np

from protocols.network import LinkConfig
from sims.simulation.swarm import SwarmConfig, run_swarm

LOSSES = (0.0, 0.1, 0.3, 0.5)


def measure(loss: float, seeds, steps: int, n_robots: int) -> dict:
    """Pooled figures of the swarm at one loss rate."""
    cfg = SwarmConfig(n_robots=n_robots, link=LinkConfig(drop=loss, latency=0.005, jitter=0.01,
                                                          duplicate=0.05 if loss > 0 else 0.0))
    pos, yaw, nees3, tracked, yaw_known, msgs, byts, step_s = [], [], [], [], [], [], [], []
    for seed in seeds:
        t0 = time.perf_counter()
        run = run_swarm(cfg, seed=seed, steps=steps)
        step_s.append((time.perf_counter() - t0) / steps)
        for rep in run.reports:
            for row in rep.errors.values():
                for e in row.values():
                    pos.append(e.position)
                    if e.yaw is not None:
                        yaw.append(e.yaw)
                        nees3.append(e.nees)
        s = run.summary()
        tracked.append(s["tracked_fraction_final"])
        yaw_known.append(s["yaw_known_fraction_final"])
        duration = steps * cfg.dt
        msgs.append(run.network.total.sent / n_robots / duration)
        byts.append(run.network.total.bytes_sent / n_robots / duration)
    return {
        "loss": loss,
        "position_error_median_m": float(np.median(pos)),
        "position_error_p90_m": float(np.percentile(pos, 90)),
        "yaw_error_median_deg": float(np.degrees(np.median(yaw))) if yaw else None,
        "tracked_fraction_final": float(np.mean(tracked)),
        "yaw_known_fraction_final": float(np.mean(yaw_known)),
        "nees3_mean": float(np.mean(nees3)) if nees3 else None,
        "nees3_median": float(np.median(nees3)) if nees3 else None,
        "messages_per_robot_per_s": float(np.median(msgs)),
        "bytes_per_robot_per_s": float(np.median(byts)),
        "wall_s_per_step_median": float(np.median(step_s)),
    }


def plot(path_json, path_png) -> None:
    """Figure from the saved results: errors and traffic vs loss."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    data = json.loads(path_json.read_text())
    rows = data["results"]
    loss = [100 * r["loss"] for r in rows]
    fig, ax = plt.subplots(1, 3, figsize=(12, 3.4))
    ax[0].plot(loss, [100 * r["position_error_median_m"] for r in rows], "o-", label="median")
    ax[0].plot(loss, [100 * r["position_error_p90_m"] for r in rows], "s--", label="90th pct")
    ax[0].set(xlabel="message loss [%]", ylabel="position error [cm]", title="relative position")
    ax[0].legend()
    ax[1].plot(loss, [r["tracked_fraction_final"] for r in rows], "o-", label="tracked")
    ax[1].plot(loss, [r["yaw_known_fraction_final"] for r in rows], "s--", label="yaw known")
    ax[1].set(xlabel="message loss [%]", ylabel="fraction of pairs at 30 s", ylim=(0, 1.05), title="coverage")
    ax[1].legend()
    ax[2].plot(loss, [r["nees3_mean"] for r in rows], "o-")
    ax[2].axhline(3.0, color="grey", lw=0.8)
    ax[2].set(xlabel="message loss [%]", ylabel="mean NEES (3 = consistent)", title="filter consistency")
    fig.suptitle(f"Kanovsky swarm: {data['parameters']['n_robots']} robots, {len(data['parameters']['seeds'])} seeds")
    fig.tight_layout()
    save_figure(fig, path_png)


def main(argv=None) -> None:
    ap = parser(__doc__)
    ap.add_argument("--quick", action="store_true", help="2 seeds, 60 steps")
    args = ap.parse_args(argv)
    seeds = range(2) if args.quick else range(5)
    steps = 60 if args.quick else 150
    n_robots = 6
    info = machine()
    results = [measure(loss, seeds, steps, n_robots) for loss in LOSSES]
    ref = results[0]
    for r in results:
        r["position_error_ratio_vs_lossless"] = r["position_error_median_m"] / ref["position_error_median_m"]
    payload = {
        "benchmark": "swarm",
        "parameters": {"n_robots": n_robots, "arena_m": SwarmConfig().arena, "steps": steps, "dt_s": SwarmConfig().dt,
                       "seeds": list(seeds), "losses": list(LOSSES), "duplicate_when_lossy": 0.05,
                       "latency_s": 0.005, "jitter_s": 0.01},
        "machine": info,
        "results": results,
    }
    path = save("swarm", payload, args.out)
    plot(path, output(args.out, "swarm", ".png"))


if __name__ == "__main__":
    main()
