"""FreeSN-like assembly configurations: spherical nodes joined by struts.

A :class:`Shape` lists node centres in the assembly's root horizontal frame H_r (Liu et al. 2024 §II):
the root node sits at the origin, nodes resting on the floor have ``z = 0`` and stacked nodes a
positive ``z``. Struts join pairs of nodes (they matter to rendering and occlusion, not to the log).
The library functions return shapes with local ids ``0..n-1`` (0 is the root); :meth:`Shape.with_ids`
renames them to ids that are unique across assemblies.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "NODE_RADIUS",
    "SPACING",
    "Shape",
    "line",
    "ell",
    "triangle",
    "square",
    "tee",
    "zigzag",
    "stack",
    "tower",
    "random_lattice",
    "LIBRARY",
    "library_shape",
]

#: FreeSN node radius r_0 [m] (Liu et al. 2024 §V-D)
NODE_RADIUS = 0.06
#: default centre-to-centre node spacing along a strut [m]
SPACING = 0.25


@dataclass(frozen=True)
class Shape:
    """One configuration of an assembly.

    Attributes
    ----------
    ids : tuple[int, ...]
        Node ids; ``ids[0]`` is the root.
    centres : ndarray, shape (n, 3)
        Node centres in H_r [m]; ``centres[0]`` is the origin.
    struts : tuple[tuple[int, int], ...]
        Pairs of node ids joined by a strut.
    """

    ids: tuple[int, ...]
    centres: np.ndarray
    struts: tuple[tuple[int, int], ...] = ()

    def __post_init__(self):
        centres = np.asarray(self.centres, dtype=float).reshape(-1, 3)
        if len(centres) != len(self.ids) or len(set(self.ids)) != len(self.ids):
            raise ValueError("a shape needs one centre per unique node id")
        if not np.allclose(centres[0], 0.0):
            raise ValueError("the root node (first id) must sit at the origin of H_r")
        centres.setflags(write=False)
        object.__setattr__(self, "centres", centres)

    def as_config(self) -> dict[int, np.ndarray]:
        """Node id -> centre (3,) in H_r, as an ``ObservationLog`` step carries it."""
        return {int(i): self.centres[k].copy() for k, i in enumerate(self.ids)}

    def with_ids(self, ids) -> "Shape":
        """Return the same shape with its nodes renamed to ``ids`` (same order)."""
        ids = tuple(int(i) for i in ids)
        rename = dict(zip(self.ids, ids))
        return Shape(ids, self.centres, tuple((rename[a], rename[b]) for a, b in self.struts))

    def centre_of(self, node: int) -> np.ndarray:
        """Centre (3,) of ``node`` in H_r."""
        return self.centres[self.ids.index(node)]


def _shape(points, struts) -> Shape:
    pts = np.asarray(points, dtype=float)
    if pts.shape[1] == 2:
        pts = np.column_stack([pts, np.zeros(len(pts))])
    return Shape(tuple(range(len(pts))), pts, tuple(struts))


def _chain(n: int):
    return [(i, i + 1) for i in range(n - 1)]


def line(n: int = 3, spacing: float = SPACING) -> Shape:
    """``n`` nodes in a row along +x."""
    return _shape([(i * spacing, 0.0) for i in range(n)], _chain(n))


def ell(spacing: float = SPACING) -> Shape:
    """An L: three nodes along +x, one more along +y at the end."""
    s = spacing
    return _shape([(0, 0), (s, 0), (2 * s, 0), (2 * s, s)], _chain(4))


def triangle(spacing: float = SPACING) -> Shape:
    """An equilateral triangle of three nodes."""
    s = spacing
    return _shape([(0, 0), (s, 0), (s / 2, s * np.sqrt(3) / 2)], [(0, 1), (1, 2), (2, 0)])


def square(spacing: float = SPACING) -> Shape:
    """A square of four nodes."""
    s = spacing
    return _shape([(0, 0), (s, 0), (s, s), (0, s)], [(0, 1), (1, 2), (2, 3), (3, 0)])


def tee(spacing: float = SPACING) -> Shape:
    """A T: three nodes along +x and one along +y from the middle one."""
    s = spacing
    return _shape([(0, 0), (s, 0), (2 * s, 0), (s, s)], [(0, 1), (1, 2), (1, 3)])


def zigzag(n: int = 5, spacing: float = SPACING) -> Shape:
    """``n`` nodes alternating at +-30 deg about the x axis, struts of length ``spacing``."""
    dx, dy = spacing * np.cos(np.pi / 6), spacing * np.sin(np.pi / 6)
    return _shape([(i * dx, (i % 2) * dy) for i in range(n)], _chain(n))


def stack(spacing: float = SPACING) -> Shape:
    """A 3D stack: a floor triangle with a fourth node resting on top (a tetrahedron)."""
    s = spacing
    base = [(0, 0, 0), (s, 0, 0), (s / 2, s * np.sqrt(3) / 2, 0)]
    apex = (s / 2, s * np.sqrt(3) / 6, s * np.sqrt(2.0 / 3.0))
    return _shape(base + [apex], [(0, 1), (1, 2), (2, 0), (0, 3), (1, 3), (2, 3)])


def tower(spacing: float = SPACING) -> Shape:
    """A 3D stack with a vertical z offset: two floor nodes, one straight above the second."""
    s = spacing
    return _shape([(0, 0, 0), (s, 0, 0), (s, 0, s)], [(0, 1), (1, 2)])


def random_lattice(n: int, rng: np.random.Generator, spacing: float = SPACING, p_up: float = 0.0) -> Shape:
    """A random connected shape of ``n`` nodes grown on a square lattice from the root.

    Each new node is attached by a strut to a random existing node, on a free lattice site next to
    it (in the floor plane, or above it with probability ``p_up`` when that node rests on the floor).
    """
    sites = [(0, 0, 0)]
    struts = []
    planar = [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0)]
    while len(sites) < n:
        k = int(rng.integers(len(sites)))
        x, y, z = sites[k]
        dirs = list(planar)
        if z == 0 and rng.random() < p_up:
            dirs = [(0, 0, 1)]
        d = dirs[int(rng.integers(len(dirs)))]
        site = (x + d[0], y + d[1], z + d[2])
        if site in sites or (site[2] == 0 and (site[0], site[1], 1) in sites) or site[2] > 1:
            continue
        sites.append(site)
        struts.append((k, len(sites) - 1))
    return _shape(np.asarray(sites, dtype=float) * spacing, struts)


#: name -> builder of the deterministic library shapes
LIBRARY = {
    "single": lambda: _shape([(0, 0)], []),
    "pair": lambda: line(2),
    "line": lambda: line(3),
    "L": ell,
    "triangle": triangle,
    "square": square,
    "T": tee,
    "zigzag": zigzag,
    "stack": stack,
    "tower": tower,
}


def library_shape(name: str) -> Shape:
    """Return the library shape called ``name`` (see :data:`LIBRARY`)."""
    try:
        return LIBRARY[name]()
    except KeyError:
        raise ValueError(f"unknown shape {name!r}; known: {', '.join(LIBRARY)}") from None
