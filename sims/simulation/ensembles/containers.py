"""2D container shapes ("molds") that modules settle into, as rasterized signed-distance fields.

A shape is an implicit function on unit coordinates (x right, y up against gravity) that says which
points are inside the container. :func:`make_container` scales it so that its area holds a requested
number of modules at a nominal packing density, rasterizes it, and returns a :class:`Container` whose
signed distance (positive inside, metres) and its gradient can be sampled at module centres.

The paper's scenarios (Funiak et al. 2008 §VI-A, Fig. 5) are mimicked by ``triple`` (three dense chambers joined
by low bridges), ``sparse`` (the same chambers joined by bridges about one module wide: weak regions)
and ``open`` (a long U-shaped channel, an open loop); ``twin`` is Fig. 3's two clusters joined by a
pair of thin bridges (a loop through two weak regions); ``funnel``, ``ring`` and ``blobs`` add variety.

``capture-triple``, ``capture-sparse`` and ``capture-open`` read Fig. 5 as §VI-A describes it,
"planar slices of a 3D shape capture scenario": a box packed with modules around fixed objects
(discs) that become holes of the container. ``capture-triple`` has three discs in a row, enclosed
(a loop of modules around each, passages about 4 module diameters wide at 1,000 modules);
``capture-sparse`` the same discs with passages about 2 diameters wide (weak regions on loops);
``capture-open`` one large disc wrapped in a U up to 80 % of its height (an open loop). The
reasoning is in docs/ensemble.md, "Reading of Fig. 5".
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy import ndimage

from decentral.errors import InputError

__all__ = ["Container", "NOMINAL_PACKING", "SHAPES_2D", "make_container", "shape_mask"]

#: area fraction covered by discs in a settled random packing (measured: 0.80-0.84 here)
NOMINAL_PACKING = 0.82


@dataclass(frozen=True)
class Container:
    """A rasterized 2D container in world coordinates (metres).

    Attributes
    ----------
    sdf : ndarray, shape (H, W)
        Signed distance to the wall at each cell centre, positive inside (metres).
    grad : ndarray, shape (2, H, W)
        Unit gradient of ``sdf`` (x, y components), pointing away from the nearest wall.
    origin : ndarray, shape (2,)
        World coordinates of the centre of cell (row 0, column 0).
    cell : float
        Cell size (metres). Row index grows with y, column index with x.
    fill : float
        Fraction of the container area the modules are meant to occupy (at ``NOMINAL_PACKING``).
    """

    sdf: np.ndarray
    grad: np.ndarray
    origin: np.ndarray
    cell: float
    fill: float

    def _coords(self, x: np.ndarray) -> np.ndarray:
        """Fractional (row, column) coordinates of points ``x`` (m, 2)."""
        return np.stack([(x[:, 1] - self.origin[1]) / self.cell, (x[:, 0] - self.origin[0]) / self.cell])

    def distance(self, x: np.ndarray) -> np.ndarray:
        """Signed wall distance (m,) at points ``x`` (m, 2), bilinear; outside the raster it is negative."""
        rc = self._coords(x)
        h, w = self.sdf.shape
        r0 = np.clip(np.floor(rc[0]).astype(np.intp), 0, h - 2)
        c0 = np.clip(np.floor(rc[1]).astype(np.intp), 0, w - 2)
        fr = np.clip(rc[0] - r0, 0.0, 1.0)
        fc = np.clip(rc[1] - c0, 0.0, 1.0)
        s = self.sdf
        top = s[r0, c0] * (1 - fc) + s[r0, c0 + 1] * fc
        bottom = s[r0 + 1, c0] * (1 - fc) + s[r0 + 1, c0 + 1] * fc
        # beyond the padded raster every point is outside: extrapolate the distance along the border
        beyond = np.hypot(np.maximum(np.abs(rc[0] - np.clip(rc[0], 0, h - 1)), 0), np.abs(rc[1] - np.clip(rc[1], 0, w - 1)))
        return top * (1 - fr) + bottom * fr - beyond * self.cell

    def normal(self, x: np.ndarray) -> np.ndarray:
        """Unit inward normals (m, 2) at points ``x`` (m, 2) (nearest cell)."""
        c = np.rint(self._coords(x)).astype(np.intp)
        c[0] = np.clip(c[0], 0, self.sdf.shape[0] - 1)
        c[1] = np.clip(c[1], 0, self.sdf.shape[1] - 1)
        return self.grad[:, c[0], c[1]].T

    def free_cells(self, clearance: float) -> np.ndarray:
        """World centres (k, 2) of the cells at least ``clearance`` inside the wall."""
        rows, cols = np.nonzero(self.sdf >= clearance)
        return np.column_stack([self.origin[0] + cols * self.cell, self.origin[1] + rows * self.cell])


# --- shapes on unit coordinates: f(x, y) -> bool array, plus the bounding box (xmin, xmax, ymin, ymax)


def _rect(x, y, x0, x1, y0, y1):
    return (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)


def _chambers(bridge: float, bridge_modules: float) -> Callable:
    """Three unit chambers side by side, joined at the floor by bridges ``bridge`` high (unit
    coordinates) but at least ``bridge_modules`` module radii high, so that they stay passable."""

    def inside(x, y, rng, m):
        h = max(bridge, bridge_modules * m)
        box = _rect(x, y, 0.0, 1.0, 0.0, 1.0) | _rect(x, y, 1.3, 2.3, 0.0, 1.0) | _rect(x, y, 2.6, 3.6, 0.0, 1.0)
        return box | _rect(x, y, 0.9, 1.4, 0.0, h) | _rect(x, y, 2.2, 2.7, 0.0, h)

    return inside


def _twin(x, y, rng, m):
    # Funiak et al. 2008 Fig. 3: two dense square clusters side by side whose only links are two thin
    # bridges, one at the floor and one at mid-height, each about one module high and a few
    # modules long: the weak regions come in a pair, so the relative rotation of the clusters is
    # well determined once both are used, but not through either bridge alone
    gap = max(0.06, 5.0 * m)
    h = 2.6 * m
    left = _rect(x, y, 0.0, 1.0, 0.0, 1.0)
    right = _rect(x, y, 1.0 + gap, 2.0 + gap, 0.0, 1.0)
    low = _rect(x, y, 0.9, 1.1 + gap, 0.0, h)
    mid = _rect(x, y, 0.9, 1.1 + gap, 0.5, 0.5 + h)
    return left | right | low | mid


def _open(x, y, rng, m):
    # a U-shaped channel 0.4 wide: an open loop, long and thin (Funiak et al. 2008 Fig. 5 "open")
    outer = _rect(x, y, 0.0, 3.0, 0.0, 2.0)
    inner = _rect(x, y, 0.4, 2.6, 0.4, 2.1)
    return outer & ~inner


def _funnel(x, y, rng, m):
    # a box below a V-shaped hopper whose spout is 0.12 wide but at least 9 module radii
    w = max(0.06, 4.5 * m)
    box = _rect(x, y, 0.0, 1.4, 0.0, 0.6)
    spout = _rect(x, y, 0.7 - w, 0.7 + w, 0.6, 0.75)
    half = w + (y - 0.75) * 0.8
    hopper = (y >= 0.75) & (y <= 1.6) & (np.abs(x - 0.7) <= half)
    return box | spout | hopper


def _ring(x, y, rng, m):
    rr = np.hypot(x - 1.0, y - 1.0)
    return (rr <= 1.0) & (rr >= 0.72)


def _blobs(x, y, rng, m):
    # a chain of random overlapping discs: an amorphous, non-convex blob
    k = 5
    centres = np.zeros((k, 2))
    radii = rng.uniform(0.35, 0.7, size=k)
    for a in range(1, k):
        ang = rng.uniform(-0.9, 0.9)
        step = 0.8 * (radii[a] + radii[a - 1])
        centres[a] = centres[a - 1] + step * np.array([np.cos(ang), np.sin(ang)])
    centres -= centres.min(axis=0) - radii.max()
    m = np.zeros(np.broadcast(x, y).shape, dtype=bool)
    for c, r in zip(centres, radii):
        m |= np.hypot(x - c[0], y - c[1]) <= r
    return m


def _capture(discs: np.ndarray, neck: float, floor: float, level: float, min_gap: float):
    """A box packed with modules around fixed discs ("objects"): a planar slice of shape capture.

    Funiak et al. 2008 §VI-A: the 2D scenarios "mimic planar slices of a 3D shape capture scenario [4]", in
    which modules fill a container around an object. The objects are held in place (pressed into the
    ensemble), so they are holes in the container, not loads on the floor; modules settle around
    them under gravity up to the fill ``level`` (unit coordinates), 0.3 below the box's open top.

    Parameters
    ----------
    discs : ndarray, shape (k, 3)
        Centre x, centre y and radius of each object (unit coordinates).
    neck, floor : float
        Gap between the outermost discs and the side walls, and between the discs and the floor
        (the box is sized from them).
    level : float
        Fill level the modules are meant to settle to (sets the shape's fill fraction).
    min_gap : float
        Smallest gap, in module radii, between a disc and a wall, the floor or another disc: at
        small module counts the discs shrink (centres fixed) so every passage stays passable.

    Returns
    -------
    inside, bounding box, fill fraction
        The ``SHAPES_2D`` entry; the fill fraction is a cached function, measured on a fine raster
        only when a container of this shape is first made (not when the module is imported).
    """
    x1 = float(discs[:, 0].max() + discs[:, 2].max() + neck)
    y1 = level + 0.3

    def radii(m):
        g = min_gap * m
        r = np.minimum(discs[:, 2], np.minimum(discs[:, 0], x1 - discs[:, 0]) - g)
        r = np.minimum(r, discs[:, 1] - g)
        if len(discs) > 1:
            pitch = np.diff(discs[:, 0])
            half = 0.5 * (pitch - g)
            r = np.minimum(r, np.minimum(np.r_[half, np.inf], np.r_[np.inf, half]))
        return r

    def inside(x, y, rng, m):
        box = _rect(x, y, 0.0, x1, 0.0, y1)
        for (cx, cy, _), r in zip(discs, radii(m)):
            box &= np.hypot(x - cx, y - cy) > r
        return box

    @functools.cache
    def fill() -> float:
        # the share of the container's area below the fill level (fine raster, unit scale)
        ys, xs = np.mgrid[0.0:y1:1000j, 0.0:x1:1000j]
        mask = inside(xs, ys, None, 0.0)
        return float(mask[ys <= level].sum() / mask.sum())

    return inside, (0.0, x1, 0.0, y1), fill


def _capture_row(radius: float, gap: float, cover: float, min_gap: float):
    """Three equal discs in a row, ``gap`` from each other, the side walls and the floor, covered
    by ``cover`` of modules above their tops (Funiak et al. 2008 Fig. 5(b) "structured triple", read as shape
    capture of three objects)."""
    pitch = 2.0 * radius + gap
    cx = gap + radius + pitch * np.arange(3)
    discs = np.column_stack([cx, np.full(3, gap + radius), np.full(3, radius)])
    return _capture(discs, gap, gap, gap + 2.0 * radius + cover, min_gap)


#: name -> (inside(x, y, rng), bounding box on unit coordinates, fill fraction or a function giving it)
SHAPES_2D: dict[str, tuple[Callable, tuple[float, float, float, float], float | Callable[[], float]]] = {
    "triple": (_chambers(0.22, 6.0), (0.0, 3.6, 0.0, 1.0), 0.92),
    "sparse": (_chambers(0.0, 4.4), (0.0, 3.6, 0.0, 1.0), 0.92),
    "open": (_open, (0.0, 3.0, 0.0, 2.0), 0.90),
    "twin": (_twin, (0.0, 2.2, 0.0, 1.0), 0.92),
    "funnel": (_funnel, (0.0, 1.4, 0.0, 1.6), 0.85),
    "ring": (_ring, (0.0, 2.0, 0.0, 2.0), 1.0),
    "blobs": (_blobs, (0.0, 8.0, -3.0, 5.0), 0.92),
    # shape capture (see docs/ensemble.md "Reading of Fig. 5"): passages ~4 module diameters wide
    # at 1,000 modules in capture-triple, ~2 in capture-sparse; capture-open wraps one large object
    # in a U up to 80 % of its height (an open loop)
    "capture-triple": _capture_row(0.4, 0.25, 0.45, 6.0),
    "capture-sparse": _capture_row(0.4, 0.10, 0.45, 3.6),
    "capture-open": _capture(np.array([[1.5, 1.45, 1.2]]), 0.3, 0.25, 0.25 + 1.6 * 1.2, 6.0),
}


def shape_mask(
    name: str, resolution: int, rng: np.random.Generator, module: float = 0.0
) -> tuple[np.ndarray, float, np.ndarray]:
    """Rasterize shape ``name`` on unit coordinates (``module``: the module radius in unit coordinates).

    Returns
    -------
    mask : ndarray of bool, shape (H, W)
        Inside cells, row index growing with y.
    unit_cell : float
        Cell size in unit coordinates.
    unit_origin : ndarray, shape (2,)
        Unit coordinates of the centre of cell (0, 0).
    """
    if name not in SHAPES_2D:
        raise InputError(f"unknown 2D shape {name!r} (known: {', '.join(sorted(SHAPES_2D))})", field="shape")
    inside, (x0, x1, y0, y1), _ = SHAPES_2D[name]
    cell = max(x1 - x0, y1 - y0) / resolution
    xs = np.arange(x0 - 2 * cell, x1 + 2 * cell, cell)
    ys = np.arange(y0 - 2 * cell, y1 + 2 * cell, cell)
    X, Y = np.meshgrid(xs, ys)
    mask = inside(X, Y, rng, module)
    if name == "blobs":  # the blob chain's own box is data-dependent: crop to it
        rows, cols = np.nonzero(mask)
        mask = mask[rows.min() - 2 : rows.max() + 3, cols.min() - 2 : cols.max() + 3]
        xs, ys = xs[cols.min() - 2 :], ys[rows.min() - 2 :]
    return mask, cell, np.array([xs[0], ys[0]])


def make_container(name: str, n: int, radius: float, rng: np.random.Generator) -> Container:
    """Scale shape ``name`` to hold ``n`` modules of ``radius`` and rasterize it at radius / 2.

    The container area is ``n * pi * radius**2 / (NOMINAL_PACKING * fill)``, so a ``fill`` below one
    leaves head room at the top of each chamber once the modules have settled under gravity.
    """
    if n < 1 or not radius > 0:
        raise InputError("need n >= 1 and radius > 0", field="n/radius")
    fill = SHAPES_2D.get(name, (None, None, 1.0))[2]
    fill = fill() if callable(fill) else fill
    coarse, ucell, _ = shape_mask(name, 400, rng_copy(rng))
    unit_area = coarse.sum() * ucell**2
    area = n * np.pi * radius**2 / (NOMINAL_PACKING * fill)
    scale = np.sqrt(area / unit_area)  # metres per unit
    cell = radius / 2.0
    resolution = int(np.ceil(max(_extent(coarse, ucell)) * scale / cell))
    mask, ucell, uorigin = shape_mask(name, max(resolution, 16), rng, radius / scale)
    cell = ucell * scale
    # pad so that the distance outside the walls is well defined on every side
    mask = np.pad(mask, 4)
    origin = (uorigin - 4 * ucell) * scale
    # the transform measures to the nearest cell centre across the wall: the wall is half a cell nearer
    inside = ndimage.distance_transform_edt(mask) * cell
    outside = ndimage.distance_transform_edt(~mask) * cell
    sdf = np.where(mask, inside - 0.5 * cell, 0.5 * cell - outside)
    gy, gx = np.gradient(sdf)
    norm = np.hypot(gx, gy)
    norm[norm == 0] = 1.0
    grad = np.stack([gx / norm, gy / norm])
    return Container(sdf=sdf, grad=grad, origin=origin, cell=float(cell), fill=float(fill))


def _extent(mask: np.ndarray, cell: float) -> tuple[float, float]:
    return mask.shape[1] * cell, mask.shape[0] * cell


def rng_copy(rng: np.random.Generator) -> np.random.Generator:
    """A generator in the same state as ``rng`` (so a random shape is drawn identically twice)."""
    g = np.random.Generator(type(rng.bit_generator)())
    g.bit_generator.state = rng.bit_generator.state
    return g
