"""Message complexity of the distributed localization (Funiak et al. 2008 §VI-F, Fig. 11 and 12).

For ensembles of growing size (2D ``triple`` scenario, settled under gravity, fixed seeds) it runs
:func:`sims.runners.ensemble_distributed.run_distributed` over the lossless simulated network, records the
messages sent per module and per phase, fits messages per module against ``a + b ln N`` (least
squares, R^2 reported), and saves ``OUT/NAME.json`` and ``.png`` (``--out``, default
``out/benchmarks``; ``--name``, default ``ensemble_messages``).
Each level's refinement stops at the same gradient tolerance (Funiak et al. 2008 §VI-B: "each estimate reaches
a fixed level of accuracy, as measured by the norm of the gradient"), ``--gtol`` module radii on
the largest entry, with a convergence check every 5 iterations: the configuration of
``decentral ensemble OBS.npz -o EST.npz --distributed --tol GTOL --check-every 5``, so one row is one
such command on the ensemble of that size. The centralized Algorithm 1 on the same input is timed as
the reference.

The refinement (about 90 % of the messages) runs through the batched path
(:class:`agents.modules.BatchedRefinement`: the same messages, bytes and rounds as the per-message
path, tested equal); every other phase sends message objects one by one. Besides the 2D sweep, the
seed's Fig. 12 table is reproduced on 3D cubic lattices of 5 x 5 x 5 and 10 x 10 x 10 modules.

Usage::

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python benchmarks/ensemble_messages.py \\
        [--sizes 250 500 1000 2000 4000 8000 20000] [--gtol 0.01] [--shape triple] [--budget 5400]
        [--cubes 5 10] [--merge PREVIOUS.json]

Each size's ensemble is generated from ``default_rng([seed, N])``, so a size gives the same
ensemble whatever else is in the sweep, and ``--merge`` can add sizes to an earlier result. The JSON
is rewritten after every size. ``--budget`` (seconds) stops the sweep before a size whose predicted
run time (the previous size's time scaled by N) would exceed what is left; skipped sizes are listed.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import json  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _common import output, parser, save_figure  # noqa: E402
from decentral.ensemble import EnsembleProblem, normcut_localize  # noqa: E402
from sims.runners.ensemble_run import distributed_config  # noqa: E402
from sims.simulation.ensembles import EnsembleSpec, generate  # noqa: E402
from sims.runners.ensemble_distributed import DistributedConfig, run_distributed  # noqa: E402
from sims.io.atomic import write_json_atomic  # noqa: E402


def fit_log(n: np.ndarray, y: np.ndarray) -> dict:
    """Least-squares y = a + b ln n, with R^2."""
    A = np.column_stack([np.ones(n.size), np.log(n)])
    (a, b), *_ = np.linalg.lstsq(A, y, rcond=None)
    pred = A @ np.array([a, b])
    ss_res = float(np.sum((y - pred) ** 2))
    ss_tot = float(np.sum((y - y.mean()) ** 2))
    return {"a": float(a), "b": float(b), "r2": 1.0 - ss_res / ss_tot if ss_tot > 0 else 1.0, "log": "natural"}


def _distributed_row(prob, cfg, seed, central=None) -> dict:
    load0 = os.getloadavg()
    t0, c0 = time.perf_counter(), time.process_time()
    res = run_distributed(prob, np.random.default_rng(seed), cfg)
    t_dist, c_dist = time.perf_counter() - t0, time.process_time() - c0
    total = int(res.messages.sum())
    phases = dict(zip(res.phase_names, (int(v) for v in res.phase_messages)))
    row = {
        "n": prob.n,
        "dim": prob.dim,
        "edges": int(prob.num_observations),
        "mean_degree": prob.num_observations / prob.n,
        "levels": res.levels,
        "messages_total": total,
        "messages_per_module": total / prob.n,
        "messages_per_module_median": float(np.median(res.messages)),
        "messages_per_module_max": int(res.messages.max()),
        "phase_messages": phases,
        "phase_share": {k: v / total for k, v in phases.items()},
        # a refinement iteration counted as one local broadcast per module instead of one message per neighbour
        "refine_share_rounds_per_module": res.info["refine_share_rounds"] / prob.n,
        "refine_pose_shares_per_module": res.info["refine_pose_shares"] / prob.n,
        # the same run with each refinement iteration counted as one local broadcast per module
        "messages_per_module_broadcast_count": (total - res.info["refine_pose_shares"]
                                                + res.info["refine_share_rounds"]) / prob.n,
        "refine_iterations_per_level": {str(k2): v for k2, v in res.info["refine_iterations"].items()},
        "rounds": res.rounds,
        "bytes_sent": res.network["total"]["bytes_sent"],
        "batched_refinement": res.info["batched"],
        "seconds_distributed": t_dist,
        "cpu_seconds_distributed": c_dist,
        "seconds_batched_refinement": res.info["seconds_batched_refinement"],
        "cost_distributed": res.cost,
        "loadavg_before": load0,
        "loadavg_after": os.getloadavg(),
    }
    if central is not None:
        row.update(central)
        row["ratio_distributed_to_centralized_time"] = t_dist / max(central["seconds_centralized"], 1e-9)
    return row


def _config(gtol: float) -> DistributedConfig:
    """The CLI's ``--distributed --tol GTOL --check-every 5`` (one definition for both)."""
    return distributed_config(tol=gtol, check_every=5)


def run(sizes, shape, gtol, budget, seed, save=None):
    cfg = _config(gtol)
    hier = cfg.hierarchy
    rows, skipped = [], []
    t_start = time.perf_counter()
    for n in sizes:
        left = budget - (time.perf_counter() - t_start)
        if rows:
            guess = rows[-1]["seconds_distributed"] * n / rows[-1]["n"] * 1.25
            if guess > left:
                skipped.append({"n": n, "predicted_seconds": guess, "seconds_left": left})
                print(f"skip N={n}: predicted {guess:.0f} s > {left:.0f} s left", flush=True)
                continue
        ens = generate(EnsembleSpec(shape=shape, n=n), np.random.default_rng([seed, n]))
        prob = EnsembleProblem.create(ens.dim, ens.n, ens.radius, ens.i, ens.j, ens.z)
        t0, c0 = time.perf_counter(), time.process_time()
        central = normcut_localize(prob, np.random.default_rng(seed))
        ref = {"seconds_centralized": time.perf_counter() - t0, "cpu_seconds_centralized": time.process_time() - c0,
               "cost_centralized": central.cost}
        row = _distributed_row(prob, cfg, seed, ref)
        row["requested"] = n
        rows.append(row)
        print(f"N={prob.n:6d} levels {row['levels']:2d} msgs/module {row['messages_per_module']:8.1f} "
              f"({row['seconds_distributed']:.1f} s wall, {row['cpu_seconds_distributed']:.1f} s CPU; "
              f"centralized {ref['seconds_centralized']:.2f} s) load {row['loadavg_before'][0]:.1f}", flush=True)
        if save is not None:
            save(rows, skipped)
    return rows, skipped, {"gtol": gtol, "check_every": cfg.check_every, "leaf_size": hier.leaf_size,
                           "abstract_size": hier.abstract_size, "step": cfg.step, "momentum": cfg.momentum,
                           "shape": shape, "seed": seed, "loss": cfg.loss, "ensemble_rng": "default_rng([seed, N])",
                           "cli": f"decentral ensemble OBS.npz -o EST.npz --distributed --tol {gtol} --check-every 5 "
                                  f"--seed {seed}"}


def run_cubes(sides, gtol, seed) -> list[dict]:
    """Funiak et al. 2008 Fig. 12's test cases: cubic lattices of side^3 modules (a box on the cubic lattice)."""
    out = []
    for side in sides:
        n = side ** 3
        ens = generate(EnsembleSpec(shape="box", n=n, lattice="cubic"), np.random.default_rng([seed, n]))
        prob = EnsembleProblem.create(ens.dim, ens.n, ens.radius, ens.i, ens.j, ens.z)
        row = _distributed_row(prob, _config(gtol), seed)
        row["case"] = f"{side}x{side}x{side}"
        out.append(row)
        print(f"cube {row['case']}: msgs/module {row['messages_per_module']:.1f}, refinement "
              f"{100 * row['phase_share']['refinement']:.1f} % ({row['seconds_distributed']:.1f} s)", flush=True)
    return out


def fit_power(n: np.ndarray, y: np.ndarray) -> dict:
    """Least-squares ln y = ln c + p ln n (the alternative to a + b ln n), with R^2 on y."""
    A = np.column_stack([np.ones(n.size), np.log(n)])
    (lc, p), *_ = np.linalg.lstsq(A, np.log(y), rcond=None)
    pred = np.exp(lc + p * np.log(n))
    ss_res = float(np.sum((y - pred) ** 2))
    ss_tot = float(np.sum((y - y.mean()) ** 2))
    return {"c": float(np.exp(lc)), "p": float(p), "r2": 1.0 - ss_res / ss_tot if ss_tot > 0 else 1.0}


def _split_bars(ax, picks, labels, title) -> None:
    phases = list(picks[0]["phase_messages"])
    bottom = np.zeros(len(picks))
    for ph in phases:
        share = np.array([100.0 * r["phase_messages"][ph] / r["messages_total"] for r in picks])
        ax.bar(labels, share, bottom=bottom, label=ph)
        for x, (b, v) in enumerate(zip(bottom, share)):
            if v >= 3:
                ax.text(x, b + v / 2, f"{v:.1f}%", ha="center", va="center", fontsize=7)
        bottom += share
    ax.set_ylabel("% of messages")
    ax.set_title(title, fontsize=10)


def plot(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = result["rows"]
    cubes = result.get("cubes", [])
    n = np.array([r["n"] for r in rows], float)
    y = np.array([r["messages_per_module"] for r in rows])
    ncol = 3 if cubes else 2
    fig, axes = plt.subplots(ncol, 1, figsize=(8.2, 4.2 * ncol))  # stacked, ~900 px wide: readable at README width
    ax1 = axes[0]
    ax1.plot(n, y, "o-", label="measured (mean per module)")
    xs = np.geomspace(n.min(), n.max(), 50)
    if "fit" in result:
        f = result["fit"]
        ax1.plot(xs, f["a"] + f["b"] * np.log(xs), "--",
                 label=f"{f['a']:.0f} + {f['b']:.0f} ln N  (R$^2$ = {f['r2']:.3f})")
    if "fit_power" in result:
        f = result["fit_power"]
        ax1.plot(xs, f["c"] * xs ** f["p"], ":", label=f"{f['c']:.0f} N^{f['p']:.3f}  (R$^2$ = {f['r2']:.3f})")
    if all("messages_per_module_broadcast_count" in r for r in rows):
        yb = np.array([r["messages_per_module_broadcast_count"] for r in rows])
        lab = "refinement as one local broadcast per iteration"
        if "fit_broadcast_count" in result:
            f = result["fit_broadcast_count"]
            lab += f": {f['a']:.0f} + {f['b']:.0f} ln N (R$^2$ = {f['r2']:.3f})"
        ax1.plot(n, yb, "s-", ms=4, label=lab)
    for r in rows:
        ax1.annotate(f"{r['levels']} lv", (r["n"], r["messages_per_module"]), textcoords="offset points",
                     xytext=(4, -10), fontsize=7)
    ax1.set_xscale("log")
    from matplotlib.ticker import NullFormatter

    ax1.set_xticks(n)
    ax1.set_xticklabels([f"{int(v):,}" for v in n], fontsize=8)
    ax1.xaxis.set_minor_formatter(NullFormatter())
    ax1.set_xlabel("modules N (2D triple)")
    ax1.set_ylabel("messages sent per module")
    ax1.set_title("messages per module (cf. Funiak et al. 2008, Fig. 11)", fontsize=10)
    ax1.legend(fontsize=8, loc="upper left")
    ax1.set_ylim(0, 1.35 * y.max())
    picks = [rows[0], rows[-1]] if len(rows) > 1 else rows
    _split_bars(axes[1], picks, [f"N={r['n']}" for r in picks], "Fig. 12: split by phase (2D)")
    if cubes:
        _split_bars(axes[2], cubes, [r["case"] for r in cubes], "Fig. 12: split by phase (3D cubic)")
    axes[-1].legend(fontsize=8, loc="best")
    fig.tight_layout()
    save_figure(fig, path)


def main(argv=None) -> int:
    ap = parser(__doc__)
    ap.add_argument("--sizes", type=int, nargs="*", default=[250, 500, 1000, 2000, 4000, 8000, 20000])
    ap.add_argument("--shape", default="triple")
    ap.add_argument("--gtol", type=float, default=0.01)
    ap.add_argument("--budget", type=float, default=5400.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cubes", type=int, nargs="*", default=[5, 10], help="sides of the 3D cubic test cases")
    ap.add_argument("--name", default="ensemble_messages", help="results file stem (default ensemble_messages)")
    ap.add_argument("--merge", help="a previous result JSON of the same parameters whose rows to include")
    ap.add_argument("--replot", action="store_true", help="only redraw the PNG from the saved JSON")
    args = ap.parse_args(argv)
    if args.replot:
        with open(output(args.out, args.name), encoding="utf-8") as fh:
            plot(json.load(fh), output(args.out, args.name, ".png"))
        return 0
    t0 = time.perf_counter()
    out = output(args.out, args.name, "")
    old = None
    if args.merge:
        with open(args.merge, encoding="utf-8") as fh:
            old = json.load(fh)
    import scipy

    def save(rows, skipped, params=None, cubes=None) -> dict:
        if old is not None:
            have = {r["requested"] for r in rows}
            rows = sorted([r for r in old["rows"] if r["requested"] not in have] + rows, key=lambda r: r["n"])
            skipped = [s for s in old.get("skipped", []) if s["n"] not in have] + skipped
            if cubes is None:
                cubes = old.get("cubes", [])
        result = {
            "benchmark": "ensemble_messages",
            "parameters": params or (old or {}).get("parameters", {}),
            "machine": {"platform": platform.platform(), "python": platform.python_version(),
                        "cpus": os.cpu_count(), "blas_threads": os.environ.get("OPENBLAS_NUM_THREADS")},
            "versions": {"numpy": np.__version__, "scipy": scipy.__version__},
            "rows": rows,
            "skipped": skipped,
            "cubes": cubes or [],
            "seconds_total": time.perf_counter() - t0,
        }
        if len(rows) >= 2:
            n = np.array([r["n"] for r in rows], float)
            y = np.array([r["messages_per_module"] for r in rows])
            result["fit"] = fit_log(n, y)
            result["fit_power"] = fit_power(n, y)
            result["fit_without_refinement"] = fit_log(n, np.array(
                [(r["messages_total"] - r["phase_messages"]["refinement"]) / r["n"] for r in rows]))
            result["fit_refinement_broadcasts"] = fit_log(n, np.array(
                [r["refine_share_rounds_per_module"] for r in rows]))
            result["fit_levels"] = fit_log(n, np.array([r["levels"] for r in rows], float))
            if all("messages_per_module_broadcast_count" in r for r in rows):
                result["fit_broadcast_count"] = fit_log(n, np.array(
                    [r["messages_per_module_broadcast_count"] for r in rows]))
        write_json_atomic(out.with_suffix(".json"), result)
        if rows:
            plot(result, out.with_suffix(".png"))
        return result

    rows, skipped, params = run(args.sizes, args.shape, args.gtol, args.budget, args.seed,
                                save=lambda r, s: save(r, s))
    if old is not None and {k: v for k, v in old["parameters"].items() if k != "seed"} != \
            {k: v for k, v in params.items() if k != "seed"}:
        raise SystemExit("--merge: parameters differ")
    cubes = run_cubes(args.cubes, args.gtol, args.seed) if args.cubes else None
    result = save(rows, skipped, params, cubes)
    if "fit" in result:
        print("fit messages/module = a + b ln N:", result["fit"])
        print("power fit:", result["fit_power"])
    print(f"wrote {out.with_suffix('.json')} and .png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
