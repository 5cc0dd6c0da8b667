"""Message complexity of the distributed localization (seed 003 §VI-F, Fig. 11 and 12).

For ensembles of growing size (2D ``triple`` scenario, settled under gravity, fixed seeds) it runs
:func:`sims.ensembles.distributed.run_distributed` over the lossless simulated network, records the
messages sent per module and per phase, fits messages per module against ``a + b ln N`` (least
squares, R^2 reported), and saves ``benchmarks/results/ensemble_messages.json`` and ``.png``.
Each level's refinement stops at the same gradient tolerance (seed 003 §VI-B: "each estimate reaches
a fixed level of accuracy, as measured by the norm of the gradient"), ``--gtol`` module radii on
the largest entry. The centralized Algorithm 1 on the same input is timed as the reference.

Usage::

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python benchmarks/ensemble_messages.py \\
        [--sizes 125 250 500 1000 2000] [--gtol 0.01] [--shape triple] [--budget 1500]

``--budget`` (seconds) stops the sweep before a size whose predicted run time (from the previous
size's time per message) would exceed what is left; skipped sizes are listed in the JSON.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from decentral.ensemble import EnsembleProblem, HierarchyConfig, RefineConfig, normcut_localize  # noqa: E402
from sims.ensembles import EnsembleSpec, generate  # noqa: E402
from sims.ensembles.distributed import DistributedConfig, run_distributed  # noqa: E402
from sims.io.atomic import write_atomic, write_json_atomic  # noqa: E402


def fit_log(n: np.ndarray, y: np.ndarray) -> dict:
    """Least-squares y = a + b ln n, with R^2."""
    A = np.column_stack([np.ones(n.size), np.log(n)])
    (a, b), *_ = np.linalg.lstsq(A, y, rcond=None)
    pred = A @ np.array([a, b])
    ss_res = float(np.sum((y - pred) ** 2))
    ss_tot = float(np.sum((y - y.mean()) ** 2))
    return {"a": float(a), "b": float(b), "r2": 1.0 - ss_res / ss_tot if ss_tot > 0 else 1.0, "log": "natural"}


def run(sizes, shape, gtol, budget, seed):
    hier = HierarchyConfig(level_refine=RefineConfig(max_iter=100, gtol=gtol))
    cfg = DistributedConfig(hierarchy=hier, top_gtol=gtol, check_every=5)
    rows, skipped = [], []
    t_start = time.perf_counter()
    per_msg = None
    for k, n in enumerate(sizes):
        ens = generate(EnsembleSpec(shape=shape, n=n), np.random.default_rng(seed + k))
        prob = EnsembleProblem.create(ens.dim, ens.n, ens.radius, ens.i, ens.j, ens.z)
        left = budget - (time.perf_counter() - t_start)
        if per_msg is not None and rows:
            guess = per_msg * rows[-1]["messages_per_module"] * 1.3 * prob.n
            if guess > left:
                skipped.append({"n": n, "predicted_seconds": guess, "seconds_left": left})
                print(f"skip N={n}: predicted {guess:.0f} s > {left:.0f} s left", flush=True)
                continue
        t0 = time.perf_counter()
        central = normcut_localize(prob, np.random.default_rng(seed))
        t_central = time.perf_counter() - t0
        load0 = os.getloadavg()
        t0 = time.perf_counter()
        res = run_distributed(prob, np.random.default_rng(seed), cfg)
        t_dist = time.perf_counter() - t0
        total = int(res.messages.sum())
        per_msg = t_dist / max(total, 1)
        row = {
            "n": prob.n,
            "requested": n,
            "edges": int(prob.num_observations),
            "levels": res.levels,
            "messages_total": total,
            "messages_per_module": total / prob.n,
            "messages_per_module_median": float(np.median(res.messages)),
            "messages_per_module_max": int(res.messages.max()),
            "phase_messages": dict(zip(res.phase_names, (int(v) for v in res.phase_messages))),
            "refine_iterations_per_level": {str(k2): v for k2, v in res.info["refine_iterations"].items()},
            "rounds": res.rounds,
            "seconds_distributed": t_dist,
            "seconds_centralized": t_central,
            "ratio_distributed_to_centralized_time": t_dist / max(t_central, 1e-9),
            "cost_distributed": res.cost,
            "cost_centralized": central.cost,
            "loadavg_before": load0,
            "loadavg_after": os.getloadavg(),
        }
        rows.append(row)
        print(f"N={prob.n:6d} levels {res.levels} msgs/module {row['messages_per_module']:8.1f} "
              f"({t_dist:.1f} s, centralized {t_central:.2f} s) load {load0[0]:.1f}", flush=True)
    return rows, skipped, {"gtol": gtol, "check_every": cfg.check_every, "leaf_size": hier.leaf_size,
                           "abstract_size": hier.abstract_size, "step": cfg.step, "momentum": cfg.momentum,
                           "shape": shape, "seed": seed, "loss": cfg.loss}


def plot(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = result["rows"]
    n = np.array([r["n"] for r in rows], float)
    y = np.array([r["messages_per_module"] for r in rows])
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    ax1.plot(n, y, "o-", label="measured (mean per module)")
    if "fit" in result:
        f = result["fit"]
        xs = np.geomspace(n.min(), n.max(), 50)
        ax1.plot(xs, f["a"] + f["b"] * np.log(xs), "--",
                 label=f"{f['a']:.0f} + {f['b']:.0f} ln N  (R$^2$ = {f['r2']:.3f})")
    ax1.set_xscale("log")
    ax1.set_xlabel("modules N")
    ax1.set_ylabel("messages sent per module")
    ax1.set_title("seed 003 Fig. 11: messages per module")
    ax1.legend(fontsize=8)
    phases = list(rows[0]["phase_messages"])
    picks = [rows[0], rows[-1]] if len(rows) > 1 else rows
    bottom = np.zeros(len(picks))
    for ph in phases:
        share = np.array([100.0 * r["phase_messages"][ph] / r["messages_total"] for r in picks])
        ax2.bar([f"N={r['n']}" for r in picks], share, bottom=bottom, label=ph)
        bottom += share
    ax2.set_ylabel("% of messages")
    ax2.set_title("seed 003 Fig. 12: split by phase")
    ax2.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.0, 0.5))
    fig.tight_layout()
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    write_atomic(path, lambda fh: fh.write(buf.getvalue()), binary=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[125, 250, 500, 1000, 2000, 5000, 10000, 20000])
    ap.add_argument("--shape", default="triple")
    ap.add_argument("--gtol", type=float, default=0.01)
    ap.add_argument("--budget", type=float, default=1500.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "ensemble_messages"))
    ap.add_argument("--merge", help="a previous result JSON of the same parameters whose rows to include")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    rows, skipped, params = run(args.sizes, args.shape, args.gtol, args.budget, args.seed)
    if args.merge:
        with open(args.merge, encoding="utf-8") as fh:
            old = json.load(fh)
        if {k: v for k, v in old["parameters"].items() if k != "seed"} != {k: v for k, v in params.items() if k != "seed"}:
            raise SystemExit("--merge: parameters differ")
        have = {r["requested"] for r in rows}
        rows = sorted([r for r in old["rows"] if r["requested"] not in have] + rows, key=lambda r: r["n"])
        skipped = [s for s in old.get("skipped", []) if s["n"] not in have] + skipped
    import scipy

    result = {
        "benchmark": "ensemble_messages",
        "parameters": params,
        "machine": {"platform": platform.platform(), "python": platform.python_version(),
                    "cpus": os.cpu_count(), "blas_threads": os.environ.get("OPENBLAS_NUM_THREADS")},
        "versions": {"numpy": np.__version__, "scipy": scipy.__version__},
        "rows": rows,
        "skipped": skipped,
        "seconds_total": time.perf_counter() - t0,
    }
    if len(rows) >= 2:
        n = np.array([r["n"] for r in rows], float)
        result["fit"] = fit_log(n, np.array([r["messages_per_module"] for r in rows]))
        result["fit_without_refinement"] = fit_log(n, np.array(
            [(r["messages_total"] - r["phase_messages"]["refinement"]) / r["n"] for r in rows]))
        print("fit messages/module = a + b ln N:", result["fit"])
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(out.with_suffix(".json"), result)
    if rows:
        plot(result, out.with_suffix(".png"))
    print(f"wrote {out.with_suffix('.json')} and .png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
