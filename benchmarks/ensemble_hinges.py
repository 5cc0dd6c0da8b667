"""Hinges in 3D ensembles: the accuracy of Algorithm 1 on `triple3d` against the thickness of its rods.

`triple3d` (hcp) is three cubes joined by two thin rods. The rasterizer keeps the deepest lattice
sites, which shaves about one module off every surface; with the rods' earlier least radius of 2.2
module radii that left, at some sizes, a rod one module thick, and in 3D every contact of a single
file of modules is a hinge: the rotation of the far part about the line through the two centres
leaves the likelihood exactly unchanged (decentral.ensemble.observability), so the cubes come out
turned against each other while each cube is right in itself.

For every size N (default 2,500 4,000 4,500 6,750 7,000 7,500 8,000 9,000), generator seed and
rod floor (``--floors``, module radii; 2.2 the earlier, 3.5 the current
``sims.simulation.ensembles.lattices.THIN_PART_RADIUS["hcp"]``), in the same run: the hinges
(``hinge_pairs``), the contacts crossing the middle of each rod (the fewer), Algorithm 1 with the
defaults of ``decentral ensemble``, its global and local RMS (module radii), the RMS of each cube
after aligning that cube alone, the largest rotation between the cubes (degrees, from their own
alignments), and the maximum-likelihood estimate refined from the truth: its cost and global RMS.
Equal costs with far apart global RMS mean the data cannot tell the two apart.

Writes ``OUT/ensemble_hinges.json`` and ``ensemble_hinges.png`` (global RMS against N per floor).
Usage: ``python benchmarks/ensemble_hinges.py [--sizes N ...] [--seeds S ...] [--floors R ...]``;
``--replot`` redraws the figure from the saved JSON.
"""

from __future__ import annotations

import _common  # noqa: F401  (pins BLAS threads before numpy loads)

import json
import time
from contextlib import contextmanager

import numpy as np

from _common import output, parser, save, save_figure

CUBE_CENTRES = (-1.8, 0.0, 1.8)  # unit coordinates of `triple3d`'s cubes (half side 0.6, half length 2.4)
ROD_MIDDLES = (-0.9, 0.9)


@contextmanager
def rod_floor(radii: float):
    """Generate with the thin parts' least radius on the hcp lattice set to ``radii`` module radii."""
    from sims.simulation.ensembles import lattices

    saved = lattices.THIN_PART_RADIUS
    lattices.THIN_PART_RADIUS = {**saved, "hcp": radii}
    try:
        yield
    finally:
        lattices.THIN_PART_RADIUS = saved


def unit_x(position: np.ndarray) -> np.ndarray:
    """x of every module in the shape's unit coordinates (the ensemble spans -2.4 .. 2.4)."""
    x = position[:, 0]
    return (x - 0.5 * (x.max() + x.min())) / (0.5 * (x.max() - x.min())) * 2.4


def rod_contacts(problem, position: np.ndarray) -> int:
    """Observation pairs crossing the middle of a rod, the fewer of the two rods."""
    u, pairs = unit_x(position), problem.pairs()
    a, b = np.sort(u[pairs], axis=1).T
    return int(min(np.count_nonzero((a < m) & (b >= m)) for m in ROD_MIDDLES))


def cube_errors(estimate: np.ndarray, truth: np.ndarray, radius: float) -> tuple[list, float]:
    """RMS of each cube after its own alignment (radii) and the largest rotation between cubes (degrees)."""
    from decentral.ensemble.alignment import AlignmentStats

    u = unit_x(truth)
    rms, rotations = [], []
    for c in CUBE_CENTRES:
        m = np.abs(u - c) <= 0.6
        t = AlignmentStats.from_points(truth[m], estimate[m]).solve()
        rms.append(float(np.sqrt(np.mean(np.sum((t.apply(estimate[m]) - truth[m]) ** 2, axis=1))) / radius))
        rotations.append(t.R)
    angle = max(np.degrees(np.arccos(np.clip((np.trace(a @ b.T) - 1) / 2, -1, 1)))
                for k, a in enumerate(rotations) for b in rotations[k + 1:])
    return rms, float(angle)


def measure(n: int, seed: int, floor: float) -> dict:
    """One row: generate, find hinges, localize, score, and the MLE refined from the truth."""
    from decentral.ensemble import EnsembleProblem, RefineConfig, evaluate, refine
    from decentral.ensemble.observability import hinge_pairs
    from decentral.ensemble.rotation import quat_to_matrix
    from sims.runners.ensemble_run import localize
    from sims.simulation.ensembles import EnsembleSpec, generate

    with rod_floor(floor):
        ens = generate(EnsembleSpec(shape="triple3d", n=n), np.random.default_rng(seed))
    prob = EnsembleProblem.create(3, ens.n, ens.radius, ens.i, ens.j, ens.z)
    start = time.process_time()
    res = localize(prob, "ncut", seed)
    cpu = time.process_time() - start
    err = evaluate(res.estimate.position, ens.position, prob.pairs(), ens.radius)
    cubes, angle = cube_errors(res.estimate.position * err.scale, ens.position, ens.radius)
    mle = refine(prob, ens.position, quat_to_matrix(ens.orientation), RefineConfig(gtol=1e-6, max_iter=600))
    mle_err = evaluate(mle.position, ens.position, prob.pairs(), ens.radius)
    return {
        "n": ens.n, "seed": seed, "rod_floor": floor, "hinges": int(len(hinge_pairs(prob))),
        "rod_contacts": rod_contacts(prob, ens.position), "observations": prob.num_observations,
        "global_rms": err.global_rms, "local_rms": err.local_rms, "cube_rms": cubes,
        "cube_rotation_deg": angle, "cost": float(res.cost), "cpu_seconds": cpu,
        "mle_cost": float(mle.cost), "mle_global_rms": mle_err.global_rms,
    }


def plot(payload: dict, out) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9.0, 3.8))
    rows = payload["rows"]
    for floor, marker in zip(sorted({r["rod_floor"] for r in rows}), "os^v"):
        sel = [r for r in rows if r["rod_floor"] == floor]
        hinged = [r for r in sel if r["hinges"]]
        line, = ax.plot([r["n"] for r in sel], [r["global_rms"] for r in sel], marker, alpha=0.7,
                        label=f"rod floor {floor:g} radii: Algorithm 1")
        ax.plot([r["n"] for r in sel], [r["mle_global_rms"] for r in sel], marker, mfc="none",
                color=line.get_color(), label=f"rod floor {floor:g} radii: MLE refined from the truth")
        if hinged:
            ax.plot([r["n"] for r in hinged], [r["global_rms"] for r in hinged], "x", color="k", ms=9)
    ax.plot([], [], "x", color="k", label="has hinges (single-file rod)")
    ax.set_xlabel("modules")
    ax.set_ylabel("global RMS (module radii)")
    ax.set_yscale("log")
    ax.set_title("triple3d (hcp), Algorithm 1: global RMS by the rods' least radius")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    save_figure(fig, output(out, "ensemble_hinges", ".png"))


def main() -> None:
    ap = parser(__doc__)
    ap.add_argument("--sizes", type=int, nargs="+", default=[2500, 4000, 4500, 6750, 7000, 7500, 8000, 9000])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--floors", type=float, nargs="+", default=[2.2, 3.5],
                    help="least rod radius in module radii (2.2: the earlier generator; 3.5: the current)")
    ap.add_argument("--replot", action="store_true", help="redraw the figure from OUT/ensemble_hinges.json")
    args = ap.parse_args()
    if args.replot:
        plot(json.loads(output(args.out, "ensemble_hinges").read_text()), args.out)
        return
    rows = []
    for n in args.sizes:
        for seed in args.seeds:
            for floor in args.floors:
                rows.append(measure(n, seed, floor))
                print(json.dumps(rows[-1]), flush=True)
    payload = {"benchmark": "ensemble_hinges", "sizes": args.sizes, "seeds": args.seeds, "floors": args.floors,
               "rows": rows}
    save("ensemble_hinges", payload, args.out)
    plot(payload, args.out)


if __name__ == "__main__":
    main()
