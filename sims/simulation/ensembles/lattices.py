"""3D ensembles rasterized from solid shapes into a hexagonal-close-packed or cubic lattice (Funiak et al. 2008 §VI-A).

A shape is a signed distance function on unit coordinates (positive inside). :func:`rasterize` scales
it so that it holds slightly more lattice sites than requested, keeps the ``n`` sites deepest inside
(ties broken at random), and jitters them a little so that the contact geometry is not exact.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from decentral.errors import InputError

__all__ = ["SHAPES_3D", "LATTICES", "lattice_sites", "rasterize"]


#: Least radius of a thin part (the rods of ``triple3d``, the bar of ``dumbbell``) on each lattice, in
#: module radii. :func:`rasterize` keeps the deepest sites, which shaves about a layer of modules off
#: every surface; what is left of a thinner rod can be a single file of modules, and in 3D each
#: contact of a single file is a hinge whose rotation the observations cannot fix
#: (:mod:`decentral.ensemble.observability`). With these, no size from 200 to 30,000 modules left
#: more than a bump of a few modules on a hinge (the cubic lattice's layers are thicker: 2 radii
#: apart against 1.63, and 3.5 still left single-file rods at 9,500-10,000 cubic modules).
THIN_PART_RADIUS = {"hcp": 3.5, "cubic": 4.5}


def _sphere(p, t):
    return 1.0 - np.linalg.norm(p, axis=1)


def _box(p, t=0.0):
    q = np.abs(p) - 1.0
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
    return -(outside + np.minimum(q.max(axis=1), 0.0))


def _torus(p, t):
    ring = np.hypot(p[:, 0], p[:, 1]) - 1.0
    return 0.4 - np.hypot(ring, p[:, 2])


def _capsule(p, a, b, r):
    ab = b - a
    t = np.clip(((p - a) @ ab) / (ab @ ab), 0.0, 1.0)
    return r - np.linalg.norm(p - (a + t[:, None] * ab), axis=1)


def _dumbbell(p, t):
    left = 0.8 - np.linalg.norm(p - [-1.4, 0, 0], axis=1)
    right = 0.8 - np.linalg.norm(p - [1.4, 0, 0], axis=1)
    bar = _capsule(p, np.array([-1.4, 0, 0]), np.array([1.4, 0, 0]), max(0.25, t))
    return np.maximum(np.maximum(left, right), bar)


def _triple3d(p, t):
    # three cubes in a row joined by thin rods (several modules across): a 3D "sparse" triple
    cubes = [_box((p - [x, 0, 0]) / 0.6) * 0.6 for x in (-1.8, 0.0, 1.8)]
    rod = _capsule(p, np.array([-1.8, 0, -0.45]), np.array([1.8, 0, -0.45]), max(0.12, t))
    return np.maximum(np.maximum.reduce(cubes), rod)


#: name -> (signed distance f(p, t) on unit coordinates, t the least radius of a thin part there
#: (:data:`THIN_PART_RADIUS`); half extent)
SHAPES_3D: dict[str, tuple[Callable[[np.ndarray], np.ndarray], np.ndarray]] = {
    "sphere": (_sphere, np.array([1.0, 1.0, 1.0])),
    "box": (_box, np.array([1.0, 1.0, 1.0])),
    "torus": (_torus, np.array([1.4, 1.4, 0.4])),
    "dumbbell": (_dumbbell, np.array([2.2, 0.8, 0.8])),
    "triple3d": (_triple3d, np.array([2.4, 0.6, 0.6])),
}

#: lattice name -> sites per unit volume for nearest-neighbour spacing 1
LATTICES = {"cubic": 1.0, "hcp": np.sqrt(2.0)}


def lattice_sites(kind: str, spacing: float, half_extent: np.ndarray) -> np.ndarray:
    """All sites (m, 3) of lattice ``kind`` with nearest-neighbour ``spacing`` in the box +-``half_extent``."""
    if kind == "cubic":
        axes = [np.arange(-np.floor(h / spacing), np.floor(h / spacing) + 1) * spacing for h in half_extent]
        return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    if kind != "hcp":
        raise InputError(f"unknown lattice {kind!r} (known: cubic, hcp)", field="lattice")
    a = spacing
    dy, dz = a * np.sqrt(3.0) / 2.0, a * np.sqrt(8.0 / 3.0) / 2.0
    ix = np.arange(-np.ceil(half_extent[0] / a) - 1, np.ceil(half_extent[0] / a) + 2)
    iy = np.arange(-np.ceil(half_extent[1] / dy) - 1, np.ceil(half_extent[1] / dy) + 2)
    iz = np.arange(-np.ceil(half_extent[2] / dz) - 1, np.ceil(half_extent[2] / dz) + 2)
    I, J, K = np.meshgrid(ix, iy, iz, indexing="ij")
    odd_row, odd_layer = np.mod(J, 2), np.mod(K, 2)
    x = (I + 0.5 * odd_row + 0.5 * odd_layer) * a  # ABAB stacking: B layers shifted by (a/2, a/(2 sqrt 3))
    y = (J + odd_layer / 3.0) * dy
    z = K * dz
    sites = np.stack([x, y, z], -1).reshape(-1, 3)
    return sites[np.all(np.abs(sites) <= half_extent + 1e-9, axis=1)]


def rasterize(
    shape: str, n: int, radius: float, lattice: str, jitter: float, rng: np.random.Generator
) -> np.ndarray:
    """Module centres (n, 3) of ``n`` touching spheres of ``radius`` filling ``shape`` on ``lattice``.

    ``jitter`` is the standard deviation of the Gaussian displacement of each centre, in module radii.
    """
    if shape not in SHAPES_3D:
        raise InputError(f"unknown 3D shape {shape!r} (known: {', '.join(sorted(SHAPES_3D))})", field="shape")
    if lattice not in LATTICES:
        raise InputError(f"unknown lattice {lattice!r} (known: {', '.join(LATTICES)})", field="lattice")
    sdf, half = SHAPES_3D[shape]
    spacing = 2.0 * radius
    # unit volume of the shape, by counting a fine cubic grid
    probe = lattice_sites("cubic", 0.02 * half.max(), half)
    volume = np.count_nonzero(sdf(probe, 0.0) > 0) * (0.02 * half.max()) ** 3
    density = LATTICES[lattice] / spacing**3
    scale = (n / (density * volume)) ** (1.0 / 3.0) * 1.08
    for _ in range(8):
        sites = lattice_sites(lattice, spacing, half * scale + spacing)
        depth = sdf(sites / scale, THIN_PART_RADIUS[lattice] * radius / scale) * scale
        if np.count_nonzero(depth > 0) >= n:
            break
        scale *= 1.1
    else:  # pragma: no cover - the loop grows the shape until it fits
        raise InputError("could not fit the modules into the shape", field="n")
    order = np.lexsort((rng.random(len(sites)), -depth))[:n]
    return sites[order] + rng.normal(0.0, jitter * radius, size=(n, 3))
