"""Settle circular modules under gravity into a 2D container (vectorized position-based relaxation).

All modules start at random places in the lowest part of the container that holds them (poured
to a level surface), overlapping freely. Each iteration moves
every module down by a gravity step that shrinks to zero over the first part of the run, pushes each
overlapping pair apart by half its overlap (Jacobi, all pairs at once, pairs from a cKDTree Verlet
list rebuilt only when some module moved more than half the skin), and projects modules that cross a
wall back inside along the wall normal. The last iterations, without gravity, remove the remaining
overlaps. The result is an irregular, jammed, largely amorphous packing resting on the container floor
(Funiak et al. 2008 §VI-A generated theirs with a physics simulator; this is a cheaper stand-in that gives the
same kind of structure: dense regions, weak bridges and a free surface).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from sims.simulation.ensembles.containers import NOMINAL_PACKING, Container

__all__ = ["SettleResult", "settle"]


@dataclass(frozen=True)
class SettleResult:
    """Settled module centres and how well the relaxation converged.

    Attributes
    ----------
    position : ndarray, shape (n, 2)
        Module centres in the world frame (metres, y up).
    max_overlap : float
        Largest remaining pairwise overlap, in module radii.
    wall_violation : float
        Largest remaining penetration of a wall, in module radii.
    iterations : int
        Relaxation iterations run.
    """

    position: np.ndarray
    max_overlap: float
    wall_violation: float
    iterations: int


def _pairs(x: np.ndarray, cutoff: float) -> np.ndarray:
    p = cKDTree(x).query_pairs(cutoff, output_type="ndarray")
    return p[np.argsort(p[:, 0], kind="stable")]  # gathers by index in memory order


def settle(
    container: Container,
    n: int,
    radius: float,
    rng: np.random.Generator,
    *,
    iterations: int = 200,
    gravity: float = 0.01,
    relax: float = 0.9,
    tolerance: float = 0.05,
    max_extra: int = 200,
) -> SettleResult:
    """Drop ``n`` modules of ``radius`` into ``container`` and let them settle.

    Parameters
    ----------
    container : Container
        The mold, from :func:`sims.simulation.ensembles.containers.make_container`.
    n : int
        Number of modules.
    radius : float
        Module radius (metres).
    rng : numpy.random.Generator
        Source of the initial placement.
    iterations : int
        Iterations of the main relaxation; gravity acts during the first two thirds.
    gravity : float
        Initial gravity step per iteration, in module radii.
    relax : float
        Fraction of each pairwise overlap corrected per iteration (Jacobi under-relaxation).
    tolerance : float
        Largest overlap (module radii) accepted before the clean-up iterations stop.
    max_extra : int
        Cap on the clean-up iterations without gravity.
    """
    # pour: the modules start spread over the lowest part of the container that holds them at the
    # nominal packing density (a level "liquid" surface), so gravity only has to compact, not carry
    inside = container.free_cells(0.0)
    need = n * np.pi * radius**2 / NOMINAL_PACKING / container.cell**2
    level = np.sort(inside[:, 1])[min(int(np.ceil(need)), len(inside)) - 1]
    # every part of the container gets its share by area (narrow bridges too); the walls then push in
    free = inside[inside[:, 1] <= level]
    x = free[rng.integers(0, len(free), size=n)] + rng.uniform(-0.5, 0.5, size=(n, 2)) * container.cell
    # order modules along rows of 4-radius bands so that gathers by index stay cache-local
    band = np.floor((x[:, 1] - x[:, 1].min()) / (4 * radius))
    x = x[np.lexsort((x[:, 0], band))]
    skin = 1.0 * radius
    cutoff = 2.0 * radius + skin
    pairs = _pairs(x, cutoff)
    anchor = x.copy()
    # only modules within reach of a wall until the next rebuild need the wall test
    walled = np.flatnonzero(container.distance(x) < radius + skin)
    g_end = int(iterations * 2 / 3)
    total = iterations + max_extra
    overlap = np.inf
    it = 0
    for it in range(total):
        if it < g_end:
            x[:, 1] -= gravity * radius * (1.0 - it / g_end)
        if np.max(np.sum((x - anchor) ** 2, axis=1)) > (0.5 * skin) ** 2:
            pairs = _pairs(x, cutoff)
            anchor = x.copy()
            walled = np.flatnonzero(container.distance(x) < radius + skin)
        i, j = pairs[:, 0], pairs[:, 1]
        d = x[j] - x[i]
        dist = np.sqrt(np.einsum("ij,ij->i", d, d))
        ov = 2.0 * radius - dist
        hit = ov > 0
        overlap = float(ov[hit].max() / radius) if hit.any() else 0.0
        if it >= iterations and overlap <= tolerance:
            break
        ih, jh = i[hit], j[hit]
        corr = d[hit] * (0.5 * relax * ov[hit] / np.maximum(dist[hit], 1e-12 * radius))[:, None]
        dx = np.empty_like(x)
        for axis in range(2):
            dx[:, axis] = np.bincount(jh, corr[:, axis], n) - np.bincount(ih, corr[:, axis], n)
        x += dx
        # walls: project modules whose disc crosses the wall back along the inward normal
        s = container.distance(x[walled])
        bad = walled[s < radius]
        if len(bad):
            x[bad] += (radius - s[s < radius])[:, None] * container.normal(x[bad])
    s = container.distance(x)
    wall = float(max(0.0, np.max(radius - s)) / radius)
    return SettleResult(position=x, max_overlap=overlap, wall_violation=wall, iterations=it + 1)
