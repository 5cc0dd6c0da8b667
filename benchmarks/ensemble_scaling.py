"""Scalability of seed 003's Algorithm 1 (``decentral.ensemble.normcut_localize``) on one core.

Declared inputs: the ``triple`` 2D scenario of seed 003 §VI-B (part B's generator, settled under
gravity, 12 IR transceivers) at 1,000 to 100,000 modules, and the ``triple3d`` 3D solid rasterized
into an hcp lattice (50 sensors) at 1,000 to 20,000 modules; generator seed 0, localization seed 0,
default :class:`HierarchyConfig` (abstracted cuts with 64 leaders, leaves of 64 modules).

For each size, a child process generates the ensemble and saves it; a fresh child then reads it
(``sims.io.ensemble_npz.read_ensemble``) and measures, in the same run:

- the floor: factorizing the contact graph's reduced Laplacian and one solve (the cheapest global
  computation on the graph: centres for the true orientations);
- Algorithm 1: wall and CPU time (median of 3 runs up to 10,000 modules, 1 run above), the
  process's peak resident memory, the mean refinement iterations per module (seed 003 Fig. 6), the
  depth of the hierarchy, and the global/local RMS error (module radii) against the truth.

It prints and writes ``benchmarks/results/ensemble_scaling.json`` and ``ensemble_scaling.png``.
Targets (issue 5): 10,000 modules <= 5 s, 100,000 <= 120 s under 4 GB, and 4x the modules for at
most 4.6x the time. BLAS is pinned to one thread; the machine is shared, so the load average is
recorded and CPU time is reported beside wall time.

Each row also splits the CPU time into the top-level refinement and everything below it, and
records the top-level refinement iterations (they dominate in 3D).

Usage: ``python benchmarks/ensemble_scaling.py [--quick] [--sizes "2:2500,10000;3:5000,20000" --name STEM]``
(``--sizes`` re-measures a few sizes, e.g. when the shared machine is quiet).
"""

from __future__ import annotations

import _common  # noqa: F401  (pins BLAS threads before numpy loads)

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from _common import RESULTS, machine, save

SIZES_2D = [1000, 2500, 10000, 25000, 100000]
SIZES_3D = [1000, 5000, 20000]
SHAPE = {2: "triple", 3: "triple3d"}
ROOT = Path(__file__).resolve().parents[1]


def _generate(dim: int, n: int, folder: str) -> dict:
    from sims.ensembles.generator import EnsembleSpec, generate, save_observations, save_truth

    t = time.perf_counter()
    ens = generate(EnsembleSpec(shape=SHAPE[dim], n=n), np.random.default_rng(0))
    gen = time.perf_counter() - t
    save_observations(Path(folder) / "obs.npz", ens)
    save_truth(Path(folder) / "truth.npz", ens)
    return {"generated_modules": int(ens.n), "observations": int(len(ens.i)), "generate_s": gen}


def _measure(folder: str, repeats: int) -> dict:
    from decentral.ensemble import HierarchyConfig, evaluate, normcut_localize
    from decentral.ensemble.refine import LaplacianSolver
    from sims.ensembles.generator import load_truth
    from sims.io.ensemble_npz import read_ensemble

    prob = read_ensemble(Path(folder) / "obs.npz")
    truth = load_truth(Path(folder) / "truth.npz")
    true_pos, true_ori = truth["position"], truth["orientation"]
    from decentral.ensemble.problem import EnsembleEstimate

    R = EnsembleEstimate.orientation_to_matrix(np.asarray(true_ori), prob.dim)
    # floor: reduced Laplacian factorization + one solve on the same graph
    floor_wall, floor_cpu = [], []
    for _ in range(3):
        w0, c0 = time.perf_counter(), time.process_time()
        lap = LaplacianSolver(prob.n, prob.i, prob.j)
        lap.solve(2.0 * np.einsum("eab,eb->ea", R[prob.i], prob.z), np.zeros((prob.n, prob.dim)))
        floor_wall.append(time.perf_counter() - w0)
        floor_cpu.append(time.process_time() - c0)
    walls, cpus, res = [], [], None
    for r in range(repeats):
        w0, c0 = time.perf_counter(), time.process_time()
        res = normcut_localize(prob, np.random.default_rng(0), HierarchyConfig())
        walls.append(time.perf_counter() - w0)
        cpus.append(time.process_time() - c0)
    err = evaluate(res.estimate.position, np.asarray(true_pos), prob.pairs(), prob.radius)
    # where the time goes: everything below the top level (cuts, leaves, lower merges and their
    # refinements) measured by a run whose top refinement is skipped; the top refinement is the rest
    split = {}
    if prob.n <= 30000:
        from decentral.ensemble.refine import RefineConfig

        base = HierarchyConfig()
        c0 = time.process_time()
        normcut_localize(prob, np.random.default_rng(0),
                         HierarchyConfig(leaf_size=base.leaf_size, cut=base.cut, abstract_size=base.abstract_size,
                                         level_refine=base.level_refine, final_refine=RefineConfig(max_iter=0)))
        below = time.process_time() - c0
        split = {"below_top_cpu_s": below, "top_refine_cpu_s": float(np.median(cpus)) - below}
    top = res.hierarchy[-1]
    return {**split, "top_refine_iterations": int(top.refine_iterations), "top_refine_status": top.refine_status,
            "top_iterations_per_module_share": float(top.refine_iterations / max(res.iterations_per_module.mean(), 1e-12)),
        "n": prob.n, "dim": prob.dim, "observations": prob.num_observations,
        "wall_s": float(np.median(walls)), "cpu_s": float(np.median(cpus)), "wall_runs": walls, "cpu_runs": cpus,
        "floor_wall_s": float(np.median(floor_wall)), "floor_cpu_s": float(np.median(floor_cpu)),
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
        "iterations_per_module": float(res.iterations_per_module.mean()),
        "depth": int(res.info["depth"]), "calls": int(res.info["calls"]), "status": res.status,
        "cost": res.cost, "global_rms": err.global_rms, "local_rms": err.local_rms,
        "loadavg": list(os.getloadavg()),
    }


def _child(args: list[str]) -> dict:
    out = subprocess.run([sys.executable, __file__, *args], capture_output=True, text=True, cwd=ROOT,
                         env={**os.environ, "PYTHONPATH": str(ROOT)})
    if out.returncode != 0:
        raise RuntimeError(f"child {args} failed:\n{out.stderr}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def _ratios(rows: list[dict], key: str) -> list[dict]:
    out = []
    for a in rows:
        for b in rows:
            if 3.5 <= b["n"] / a["n"] <= 4.5:
                out.append({"from": a["n"], "to": b["n"], "size_ratio": b["n"] / a["n"],
                            "time_ratio": b[key] / a[key], "floor_ratio": b["floor_" + key] / a["floor_" + key]})
    return out


def plot(payload: dict, path: Path) -> None:
    """Time, memory and iterations per module against module count (from the saved results)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 3, figsize=(15, 4.5))
    for dim, marker in ((2, "o"), (3, "s")):
        rows = [r for r in payload["runs"] if r["dim"] == dim]
        if not rows:
            continue
        n = np.array([r["n"] for r in rows])
        ax[0].loglog(n, [r["cpu_s"] for r in rows], marker + "-", label=f"{dim}D Algorithm 1 (CPU)")
        ax[0].loglog(n, [r["wall_s"] for r in rows], marker + ":", alpha=0.6, label=f"{dim}D Algorithm 1 (wall)")
        ax[0].loglog(n, [r["floor_cpu_s"] for r in rows], marker + "--", label=f"{dim}D Laplacian factor+solve (CPU)")
        ax[1].loglog(n, [r["peak_rss_mb"] for r in rows], marker + "-", label=f"{dim}D")
        ax[2].semilogx(n, [r["iterations_per_module"] for r in rows], marker + "-", label=f"{dim}D")
    ax[0].axhline(5, color="gray", lw=0.8)
    ax[0].axhline(120, color="gray", lw=0.8)
    ax[0].set(xlabel="modules", ylabel="seconds (one core)", title="time (targets: 5 s @10k, 120 s @100k)")
    ax[1].axhline(4096, color="gray", lw=0.8)
    ax[1].set(xlabel="modules", ylabel="peak RSS of the process (MB)", title="memory (target < 4 GB)")
    ax[2].set(xlabel="modules", ylabel="refinement iterations per module", title="seed 003 Fig. 6 analogue")
    for a in ax:
        a.legend(fontsize=8)
        a.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--gen":
        print(json.dumps(_generate(int(sys.argv[2]), int(sys.argv[3]), sys.argv[4])))
        return
    if len(sys.argv) > 1 and sys.argv[1] == "--measure":
        print(json.dumps(_measure(sys.argv[2], int(sys.argv[3]))))
        return
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="small sizes only (a smoke run)")
    ap.add_argument("--sizes", help='only these sizes, e.g. "2:2500,10000;3:5000,20000" (a spot check)')
    ap.add_argument("--name", default="ensemble_scaling", help="results file stem")
    args = ap.parse_args()
    sizes = {2: [1000, 4000], 3: [1000]} if args.quick else {2: SIZES_2D, 3: SIZES_3D}
    if args.sizes:
        sizes = {2: [], 3: []}
        for part in args.sizes.split(";"):
            dim, ns = part.split(":")
            sizes[int(dim)] = [int(v) for v in ns.split(",")]
    info = machine()
    runs = []
    for dim in (2, 3):
        for n in sizes[dim]:
            with tempfile.TemporaryDirectory() as folder:
                gen = _child(["--gen", str(dim), str(n), folder])
                row = _child(["--measure", folder, "3" if n <= 10000 else "1"])
            row.update(requested=n, **gen)
            runs.append(row)
            print(f"{dim}D n={row['n']}: wall {row['wall_s']:.2f} s, cpu {row['cpu_s']:.2f} s, floor {row['floor_cpu_s']:.3f} s, "
                  f"top {row['top_refine_iterations']} it ({row.get('top_refine_cpu_s', float('nan')):.2f} s cpu), "
                  f"rss {row['peak_rss_mb']:.0f} MB, it/module {row['iterations_per_module']:.1f}, "
                  f"global rms {row['global_rms']:.2f}, load {row['loadavg'][0]:.1f}", flush=True)
    by = {(r["dim"], r["requested"]): r for r in runs}
    targets = {}
    if (2, 10000) in by:
        targets["10k_2d_le_5s"] = {"wall_s": by[(2, 10000)]["wall_s"], "cpu_s": by[(2, 10000)]["cpu_s"],
                                   "met_cpu": by[(2, 10000)]["cpu_s"] <= 5.0, "met_wall": by[(2, 10000)]["wall_s"] <= 5.0}
    if (2, 100000) in by:
        r = by[(2, 100000)]
        targets["100k_2d_le_120s_4GB"] = {"wall_s": r["wall_s"], "cpu_s": r["cpu_s"], "peak_rss_mb": r["peak_rss_mb"],
                                          "met_cpu": r["cpu_s"] <= 120 and r["peak_rss_mb"] < 4096,
                                          "met_wall": r["wall_s"] <= 120 and r["peak_rss_mb"] < 4096}
    for dim in (2, 3):
        rows = sorted((r for r in runs if r["dim"] == dim), key=lambda r: r["n"])
        targets[f"4x_{dim}d_cpu"] = _ratios(rows, "cpu_s")
        targets[f"4x_{dim}d_wall"] = _ratios(rows, "wall_s")
    payload = {
        "benchmark": "ensemble_scaling",
        "parameters": {"shapes": SHAPE, "sizes": sizes, "generator_seed": 0, "localize_seed": 0,
                       "config": "HierarchyConfig() defaults", "repeats": "3 up to 10k modules, else 1"},
        "runs": runs,
        "targets": targets,
        "machine": info,
    }
    save(args.name, payload)
    plot(payload, RESULTS / f"{args.name}.png")


if __name__ == "__main__":
    main()
