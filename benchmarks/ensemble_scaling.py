"""Scalability of Funiak et al.'s Algorithm 1 (``decentral.ensemble.normcut_localize``) on one core.

Declared inputs: the ``triple`` 2D scenario of Funiak et al. 2008 §VI-B (part B's generator, settled under
gravity, 12 IR transceivers) at 1,000 to 100,000 modules, and the ``triple3d`` 3D solid rasterized
into an hcp lattice (50 sensors) at 1,000 to 20,000 modules; generator seed 0, localization seed 0.
Configurations, measured in the same run (``--configs``):

- ``default``: :class:`HierarchyConfig` defaults (L-BFGS refiner, seam-only refinement below the
  top, 2 hops; Laplacian orderings by ``decentral.ensemble.ordering.choose_ordering``);
- ``no_coarse`` (the earlier default): the same without the two-level initial inverse Hessian of
  the top refinement (``RefineConfig(coarse_size=0)``: 4 L^-1 alone, no rigid motions of clusters);
- ``mmd_order`` (the earlier ordering rule): the same with every Laplacian ordered by SuperLU's minimum
  degree (``RefineConfig(ordering="mmd")``) instead of the default rule (METIS nested dissection for
  3D Laplacians of 4,000 modules or more, Algorithm 1's cuts as the elimination order of the other
  full-level Laplacians);
- ``full_levels`` (the original defaults): every level refined in full by Anderson-mixed
  alternating sweeps (``seam_hops=0``, ``method="alternating"``, history 6), same tolerances.

Every size is generated once by a child process. Then, for each 4x pair (2D 2,500 -> 10,000 and
25,000 -> 100,000, 3D 5,000 -> 20,000) and each configuration, fresh child processes measure the
two sizes one after the other, and the whole sweep is repeated (``--repeats``, 5 by default; the
100,000-module pair ``--repeats-large``, 3), so that both sizes of a pair see the same machine
load; medians are taken over the repeats, and each 4x ratio is given both as the ratio of the two
sizes' medians and as the median (and range) of the per-repeat ratios of back-to-back runs. Each child measures, on the same graph:

- the floor: factorizing the contact graph's reduced Laplacian and one solve (SuperLU in the
  ordering the default refiner picks for the whole graph; the cheapest global computation on the
  graph: centres for the true orientations);
- after a warm-up call on a 300-module piece of the graph (so lazily imported code paths are not
  timed), Algorithm 1 (repeated in the same process until 4 s of CPU or 7 runs, median taken, so
  that sub-second sizes are not one noisy sample): CPU time (``time.process_time``) and wall time, the process's peak
  resident memory, the mean refinement iterations per module (Funiak et al. 2008 Fig. 6), the depth of the
  hierarchy, the top refinement's iterations, the final cost and the global/local RMS error (module
  radii) against the truth, and the load average;
- on the first repeat (up to 30,000 modules), the CPU time below the top level (cuts, leaves, lower
  merges and their refinements), from a second run whose top refinement is skipped.

It prints and writes ``OUT/<name>.json`` and ``<name>.png``. Targets:
10,000 modules <= 5 s, 100,000 <= 120 s under 4 GB, and 4x the modules for at most 4.6x the time.
BLAS is pinned to one thread; the machine is shared, so CPU time is the figure of merit and the load
is recorded per run.

Usage: ``python benchmarks/ensemble_scaling.py [--quick] [--sizes "2:2500,10000;3:5000,20000"]
[--repeats 5] [--repeats-large 3] [--configs default,no_coarse] [--name STEM] [--replot]`` (configurations:
default, no_coarse, mmd_order, full_levels).
"""

from __future__ import annotations

import _common  # noqa: F401  (pins BLAS threads before numpy loads)

import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from _common import machine, output, parser, save, save_figure

SIZES_2D = [1000, 2500, 10000, 25000, 100000]
SIZES_3D = [1000, 5000, 20000]
SHAPE = {2: "triple", 3: "triple3d"}
PAIRS = [(2, 2500, 10000), (2, 25000, 100000), (3, 5000, 20000)]
CONFIGS = ("default", "no_coarse", "mmd_order", "full_levels")
DEFAULT_CONFIGS = ("default", "no_coarse")
ROOT = Path(__file__).resolve().parents[1]
INNER_CPU_S, INNER_MAX = 4.0, 7


def make_config(name: str, skip_top: bool = False):
    """The :class:`HierarchyConfig` called ``name`` (optionally without its top refinement)."""
    from dataclasses import replace

    from decentral.ensemble import HierarchyConfig, RefineConfig

    if name == "default":
        cfg = HierarchyConfig()
    elif name == "no_coarse":
        base = HierarchyConfig()
        cfg = replace(base, final_refine=replace(base.final_refine, coarse_size=0))
    elif name == "mmd_order":
        base = HierarchyConfig()
        cfg = replace(base, level_refine=replace(base.level_refine, ordering="mmd"),
                      final_refine=replace(base.final_refine, ordering="mmd"))
    elif name == "full_levels":
        cfg = HierarchyConfig(seam_hops=0, level_refine=RefineConfig(max_iter=100, gtol=1e-3),
                              final_refine=RefineConfig(max_iter=300, gtol=1e-6))
    else:
        raise ValueError(f"unknown configuration {name!r}")
    return replace(cfg, final_refine=replace(cfg.final_refine, max_iter=0)) if skip_top else cfg


def _generate(dim: int, n: int, folder: str) -> dict:
    from sims.simulation.ensembles.generator import EnsembleSpec, generate, save_observations, save_truth

    t = time.perf_counter()
    ens = generate(EnsembleSpec(shape=SHAPE[dim], n=n), np.random.default_rng(0))
    gen = time.perf_counter() - t
    save_observations(Path(folder) / "obs.npz", ens)
    save_truth(Path(folder) / "truth.npz", ens)
    return {"generated_modules": int(ens.n), "observations": int(len(ens.i)), "generate_s": gen}


def _measure(folder: str, config: str, split: bool) -> dict:
    from decentral.ensemble import evaluate, normcut_localize
    from decentral.ensemble.problem import EnsembleEstimate
    from decentral.ensemble.ordering import choose_ordering
    from decentral.ensemble.refine import LaplacianSolver
    from sims.io.ensemble_npz import read_ensemble, read_ensemble_truth

    prob = read_ensemble(Path(folder) / "obs.npz")
    truth = read_ensemble_truth(Path(folder) / "truth.npz")
    R = EnsembleEstimate.orientation_to_matrix(truth.orientation, prob.dim)
    # floor: reduced Laplacian factorization + one solve on the same graph
    floor_wall, floor_cpu = [], []
    for _ in range(3):
        w0, c0 = time.perf_counter(), time.process_time()
        lap = LaplacianSolver(prob.n, prob.i, prob.j, ordering=choose_ordering("auto", prob.dim, prob.n))
        lap.solve(2.0 * np.einsum("eab,eb->ea", R[prob.i], prob.z), np.zeros((prob.n, prob.dim)))
        floor_wall.append(time.perf_counter() - w0)
        floor_cpu.append(time.process_time() - c0)
    # warm-up on a 300-module piece: lazily imported code paths are loaded before the timed run
    normcut_localize(prob.subproblem(np.arange(min(prob.n, 300))), np.random.default_rng(0), make_config(config))
    load0 = os.getloadavg()[0]
    # short runs are repeated in the same process (until INNER_CPU_S of CPU or INNER_MAX runs) and
    # their median taken: a sub-second run alone moves by 10-30 % with the machine's speed
    walls, cpus = [], []
    while not cpus or (sum(cpus) < INNER_CPU_S and len(cpus) < INNER_MAX):
        w0, c0 = time.perf_counter(), time.process_time()
        res = normcut_localize(prob, np.random.default_rng(0), make_config(config))
        walls.append(time.perf_counter() - w0)
        cpus.append(time.process_time() - c0)
    wall, cpu = float(np.median(walls)), float(np.median(cpus))
    err = evaluate(res.estimate.position, truth.position, prob.pairs(), prob.radius)
    row = {}
    if split and prob.n <= 30000:
        # where the time goes: everything below the top level, from a run without the top refinement
        c0 = time.process_time()
        normcut_localize(prob, np.random.default_rng(0), make_config(config, skip_top=True))
        below = time.process_time() - c0
        row = {"below_top_cpu_s": below, "top_refine_cpu_s": cpu - below}
    top = res.hierarchy[-1]
    return {**row, "config": config, "n": prob.n, "dim": prob.dim, "observations": prob.num_observations,
            "wall_s": wall, "cpu_s": cpu, "inner_cpu_s": cpus,
            "floor_wall_s": float(np.median(floor_wall)), "floor_cpu_s": float(np.median(floor_cpu)),
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
            "iterations_per_module": float(res.iterations_per_module.mean()),
            "top_refine_iterations": int(top.refine_iterations), "top_refine_status": top.refine_status,
            "depth": int(res.info["depth"]), "calls": int(res.info["calls"]), "status": res.status,
            "cost": res.cost, "global_rms": err.global_rms, "local_rms": err.local_rms,
            "loadavg_start": load0, "loadavg": list(os.getloadavg())}


def _child(args: list[str]) -> dict:
    out = subprocess.run([sys.executable, __file__, *args], capture_output=True, text=True, cwd=ROOT,
                         env={**os.environ, "PYTHONPATH": str(ROOT)})
    if out.returncode != 0:
        raise RuntimeError(f"child {args} failed:\n{out.stderr}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def summarize(runs: list[dict]) -> list[dict]:
    """Median figures per (configuration, dimension, size) over the repeated runs."""
    groups: dict[tuple, list[dict]] = {}
    for r in runs:
        groups.setdefault((r["config"], r["dim"], r["n"]), []).append(r)
    out = []
    for (config, dim, n), rows in sorted(groups.items()):
        med = {k: float(np.median([r[k] for r in rows])) for k in ("cpu_s", "wall_s", "floor_cpu_s", "floor_wall_s")}
        first = rows[0]
        out.append({"config": config, "dim": dim, "n": n, "observations": first["observations"], "repeats": len(rows),
                    **med, "cpu_runs": [r["cpu_s"] for r in rows], "wall_runs": [r["wall_s"] for r in rows],
                    "load_runs": [r["loadavg_start"] for r in rows],
                    "peak_rss_mb": max(r["peak_rss_mb"] for r in rows),
                    **{k: first[k] for k in ("iterations_per_module", "top_refine_iterations", "top_refine_status",
                                             "depth", "cost", "global_rms", "local_rms", "status")},
                    **{k: first[k] for k in ("below_top_cpu_s", "top_refine_cpu_s") if k in first}})
    return out


def paired_ratios(runs: list[dict], config: str, dim: int, small: int, large: int) -> list[float]:
    """CPU-time ratios large / small of the runs made back to back in the same repeat."""
    by = {(r["repeat"], r["n"]): r["cpu_s"] for r in runs if r["config"] == config and r["dim"] == dim}
    return [by[(rep, large)] / by[(rep, small)] for rep, n in sorted(by) if n == small and (rep, large) in by]


def ratios(summary: list[dict], runs: list[dict]) -> list[dict]:
    """4x ratios for each pair of sizes about 4x apart: of the medians (CPU, wall, floor) and the
    median and range of the per-repeat CPU ratios."""
    out = []
    for a in summary:
        for b in summary:
            if a["config"] == b["config"] and a["dim"] == b["dim"] and 3.5 <= b["n"] / a["n"] <= 4.5:
                per = paired_ratios(runs, a["config"], a["dim"], a["n"], b["n"])
                out.append({"config": a["config"], "dim": a["dim"], "from": a["n"], "to": b["n"],
                            "size_ratio": b["n"] / a["n"],
                            "paired_cpu_ratios": per,
                            "paired_cpu_ratio_median": float(np.median(per)) if per else None,
                            "cpu_ratio": b["cpu_s"] / a["cpu_s"], "wall_ratio": b["wall_s"] / a["wall_s"],
                            "floor_cpu_ratio": b["floor_cpu_s"] / a["floor_cpu_s"],
                            "floor_wall_ratio": b["floor_wall_s"] / a["floor_wall_s"],
                            "met_cpu": b["cpu_s"] / a["cpu_s"] <= 4.6, "met_wall": b["wall_s"] / a["wall_s"] <= 4.6})
    return out


def plot(payload: dict, path: Path) -> None:
    """CPU time, iterations per module and 4x ratios against module count (from the saved results)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(3, 1, figsize=(8.2, 13))  # stacked, ~900 px wide: readable at README width
    styles = {"default": "-", "no_coarse": "--", "mmd_order": "-.", "full_levels": ":"}
    for dim, marker in ((2, "o"), (3, "s")):
        floor_done = False
        for config, ls in styles.items():
            rows = sorted((r for r in payload["summary"] if r["dim"] == dim and r["config"] == config),
                          key=lambda r: r["n"])
            if not rows:
                continue
            n = np.array([r["n"] for r in rows])
            ax[0].loglog(n, [r["cpu_s"] for r in rows], marker + ls, label=f"{dim}D {config} (CPU, median)")
            ax[1].semilogx(n, [r["iterations_per_module"] for r in rows], marker + ls, label=f"{dim}D {config}")
            if not floor_done:
                ax[0].loglog(n, [r["floor_cpu_s"] for r in rows], marker + "--", alpha=0.5,
                             label=f"{dim}D Laplacian factor+solve (CPU)")
                floor_done = True
    ax[0].axhline(5, color="gray", lw=0.8)
    ax[0].axhline(120, color="gray", lw=0.8)
    ax[0].set(xlabel="modules", ylabel="CPU seconds (one core)", title="time (targets: 5 s @10k, 120 s @100k)")
    ax[1].set(xlabel="modules", ylabel="refinement iterations per module", title="refinement iterations (cf. Funiak et al. 2008, Fig. 6)")
    labels, cpu, floor, colors, low, high = [], [], [], [], [], []
    for r in payload["targets"]["4x"]:
        labels.append(f"{r['dim']}D {r['from'] / 1000:.3g}k-{r['to'] / 1000:.3g}k\n{r['config']}")
        cpu.append(r["cpu_ratio"])
        floor.append(r["floor_cpu_ratio"])
        colors.append("C0" if r["config"] == "default" else "C7")
        per = r.get("paired_cpu_ratios") or [r["cpu_ratio"]]
        low.append(max(r["cpu_ratio"] - min(per), 0.0))
        high.append(max(max(per) - r["cpu_ratio"], 0.0))
    x = np.arange(len(labels))
    ax[2].bar(x - 0.2, cpu, 0.4, color=colors, yerr=[low, high], capsize=3,
              label="Algorithm 1 (CPU, ratio of medians; bars: per-repeat range)")
    ax[2].bar(x + 0.2, floor, 0.4, color="C1", alpha=0.6, label="floor: Laplacian factor+solve")
    ax[2].axhline(4.6, color="red", lw=1, label="target 4.6")
    ax[2].axhline(4.0, color="gray", lw=0.8, ls="--", label="linear (4.0)")
    ax[2].set_xticks(x, labels, fontsize=8)
    ax[2].set(ylabel="time ratio for 4x the modules", title="4x the modules")
    for a in ax:
        a.legend(fontsize=8)
        a.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    save_figure(fig, path)


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--gen":
        print(json.dumps(_generate(int(sys.argv[2]), int(sys.argv[3]), sys.argv[4])))
        return
    if len(sys.argv) > 1 and sys.argv[1] == "--measure":
        print(json.dumps(_measure(sys.argv[2], sys.argv[3], sys.argv[4] == "1")))
        return
    ap = parser(__doc__)
    ap.add_argument("--quick", action="store_true", help="small sizes only (a smoke run)")
    ap.add_argument("--sizes", help='only these sizes, e.g. "2:2500,10000;3:5000,20000" (a spot check)')
    ap.add_argument("--repeats", type=int, default=5, help="interleaved repeats of each size")
    ap.add_argument("--repeats-large", type=int, default=3, help="repeats of sizes above 50,000 modules")
    ap.add_argument("--configs", default=",".join(DEFAULT_CONFIGS), help=f"configurations to measure ({', '.join(CONFIGS)})")
    ap.add_argument("--name", default="ensemble_scaling", help="results file stem")
    ap.add_argument("--replot", action="store_true", help="only redraw the PNG from the saved JSON")
    args = ap.parse_args()
    if args.replot:
        plot(json.loads(output(args.out, args.name).read_text()), output(args.out, args.name, ".png"))
        return
    sizes = {2: [1000, 4000], 3: [1000]} if args.quick else {2: SIZES_2D, 3: SIZES_3D}
    if args.sizes:
        sizes = {2: [], 3: []}
        for part in args.sizes.split(";"):
            dim, ns = part.split(":")
            sizes[int(dim)] = [int(v) for v in ns.split(",")]
    configs = [c for c in args.configs.split(",") if c]
    for c in configs:
        if c not in CONFIGS:
            ap.error(f"--configs: unknown configuration {c!r} ({', '.join(CONFIGS)})")
    info = machine()
    # measurement groups: each 4x pair is measured back to back; other sizes on their own
    groups = [[(d, a), (d, b)] for d, a, b in PAIRS if a in sizes[d] and b in sizes[d]]
    paired = {s for g in groups for s in g}
    groups += [[(d, n)] for d in (2, 3) for n in sizes[d] if (d, n) not in paired]
    runs, gen = [], {}
    with tempfile.TemporaryDirectory() as root:
        for d in (2, 3):
            for n in sizes[d]:
                folder = os.path.join(root, f"{d}_{n}")
                os.mkdir(folder)
                gen[(d, n)] = _child(["--gen", str(d), str(n), folder])
        for rep in range(max(args.repeats, args.repeats_large)):
            for group in groups:
                if rep >= (args.repeats_large if max(n for _, n in group) > 50000 else args.repeats):
                    continue
                for config in configs:
                    for d, n in group:
                        row = _child(["--measure", os.path.join(root, f"{d}_{n}"), config, "1" if rep == 0 else "0"])
                        row.update(requested=n, repeat=rep, **gen[(d, n)])
                        runs.append(row)
                        print(f"[{rep}] {config:11s} {d}D n={row['n']}: cpu {row['cpu_s']:.2f} s, wall {row['wall_s']:.2f} s, "
                              f"floor {row['floor_cpu_s']:.3f} s, top {row['top_refine_iterations']} it, "
                              f"it/module {row['iterations_per_module']:.1f}, cost {row['cost']:.9g}, "
                              f"global rms {row['global_rms']:.3f}, load {row['loadavg_start']:.1f}", flush=True)
    summary = summarize(runs)
    targets = {"4x": ratios(summary, runs)}
    for config in configs:
        r10 = next((r for r in summary if r["config"] == config and r["dim"] == 2 and r["n"] == 10000), None)
        if r10:
            targets[f"10k_2d_le_5s_{config}"] = {"cpu_s": r10["cpu_s"], "wall_s": r10["wall_s"],
                                                 "met_cpu": r10["cpu_s"] <= 5.0, "met_wall": r10["wall_s"] <= 5.0}
        big = [r for r in summary if r["config"] == config and r["dim"] == 2 and r["n"] >= 99000]
        if big:
            r = big[0]
            targets[f"100k_2d_le_120s_4GB_{config}"] = {
                "cpu_s": r["cpu_s"], "wall_s": r["wall_s"], "peak_rss_mb": r["peak_rss_mb"],
                "met_cpu": r["cpu_s"] <= 120 and r["peak_rss_mb"] < 4096,
                "met_wall": r["wall_s"] <= 120 and r["peak_rss_mb"] < 4096}
    payload = {
        "benchmark": "ensemble_scaling",
        "parameters": {"shapes": SHAPE, "sizes": sizes, "pairs": PAIRS, "configs": configs,
                       "generator_seed": 0, "localize_seed": 0, "repeats": args.repeats,
                       "repeats_large": args.repeats_large,
                       "timing": "CPU = time.process_time of the child process; medians over interleaved repeats"},
        "summary": summary,
        "targets": targets,
        "runs": runs,
        "machine": info,
    }
    save(args.name, payload, args.out)
    plot(payload, output(args.out, args.name, ".png"))
    for r in targets["4x"]:
        per = r["paired_cpu_ratios"]
        print(f"{r['config']:11s} {r['dim']}D {r['from']} -> {r['to']}: CPU ratio of medians {r['cpu_ratio']:.2f}, "
              f"per repeat median {r['paired_cpu_ratio_median']:.2f} (range {min(per):.2f}-{max(per):.2f}), "
              f"floor {r['floor_cpu_ratio']:.2f}")


if __name__ == "__main__":
    main()
