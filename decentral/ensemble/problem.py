"""The ensemble localization problem (Funiak et al. 2008 §III-A) and its estimate, as frozen array containers.

An :class:`EnsembleProblem` holds the observations of the ``decentral.ensemble/1`` format: ``n``
modules of radius ``radius`` in ``dim`` dimensions and ``E`` directed observations ``z[e]``, the
location of the sensor of module ``i[e]`` that saw module ``j[e]``, written in module ``i[e]``'s local
frame. An :class:`EnsembleEstimate` holds one pose per module in one arbitrary global frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import sparse

from decentral.errors import InputError
from decentral.ensemble.rotation import angle_to_matrix, matrix_to_angle, matrix_to_quat, quat_to_matrix

__all__ = ["EnsembleProblem", "EnsembleEstimate", "connected_components", "MAX_MODULES", "MIN_RADIUS", "MAX_RADIUS",
           "MAX_REACH"]

#: ids are packed as ``i * n + j`` in int64, so ``n`` must stay below 2**31
MAX_MODULES = 2**31 - 1
#: physically meaningful module radii, metres (a radius of 1e-308 or 1e308 is a broken file, not a robot)
MIN_RADIUS, MAX_RADIUS = 1e-6, 1e6
#: an observation ``z`` lies on the observer's perimeter; farther than this many radii it is refused
MAX_REACH = 100.0


@dataclass(frozen=True)
class EnsembleProblem:
    """Observations of an ensemble of ``n`` circular (2D) or spherical (3D) modules.

    Attributes
    ----------
    dim : int
        2 or 3.
    n : int
        Module count; module ids are ``0 .. n-1``.
    radius : float
        Module radius (metres), > 0.
    i, j : ndarray of int, shape (E,)
        Observer and observed module of each observation; ``i != j``.
    z : ndarray, shape (E, dim)
        Observation z_{i,j}: sensor location on module i's perimeter, in i's local frame (metres).

    Notes
    -----
    Validation (:meth:`validate`) checks the contract's invariants; the constructor does not, so
    that internal sub-problems are cheap to make.
    """

    dim: int
    n: int
    radius: float
    i: np.ndarray
    j: np.ndarray
    z: np.ndarray
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    # ------------------------------------------------------------------ construction
    @classmethod
    def create(cls, dim, n, radius, i, j, z, *, source: str | None = None) -> "EnsembleProblem":
        """Build a problem from raw values and :meth:`validate` it (errors name ``source``)."""
        prob = cls(int(dim), int(n), float(radius), np.asarray(i, dtype=np.int64),
                   np.asarray(j, dtype=np.int64), np.asarray(z, dtype=float))
        prob.validate(source=source)
        return prob

    def validate(self, *, source: str | None = None) -> None:
        """Raise :class:`InputError` (naming the field) unless the contract's invariants hold.

        Checks: dim is 2 or 3, n >= 1, radius finite and > 0, ``i``/``j`` 1-D of equal length and in
        ``0..n-1``, no self-observation, ``z`` of shape (E, dim) and finite, and every observation
        (i, j) matched by its reverse (j, i), each pair at most once.
        """
        def bad(msg, fld):
            raise InputError(msg, source=source, field=fld)

        if self.dim not in (2, 3):
            bad(f"must be 2 or 3, got {self.dim}", "dim")
        if not 1 <= self.n <= MAX_MODULES:
            bad(f"must be a module count in 1..{MAX_MODULES}, got {self.n}", "n")
        if not MIN_RADIUS <= self.radius <= MAX_RADIUS:  # also refuses NaN
            bad(f"must be in [{MIN_RADIUS:g}, {MAX_RADIUS:g}] (metres), got {self.radius:g}", "radius")
        if self.i.ndim != 1:
            bad("must be a 1-D integer array", "i")
        if self.j.ndim != 1:
            bad("must be a 1-D integer array", "j")
        if self.j.shape != self.i.shape:
            bad(f"length {self.j.shape[0]} does not match len(i) = {self.i.shape[0]}", "j")
        if self.z.ndim != 2 or self.z.shape != (self.i.shape[0], self.dim):
            bad(f"must have shape (len(i), dim) = ({self.i.shape[0]}, {self.dim}), got {self.z.shape}", "z")
        for name, ids in (("i", self.i), ("j", self.j)):
            if ids.size and (ids.min() < 0 or ids.max() >= self.n):
                k = int(np.flatnonzero((ids < 0) | (ids >= self.n))[0])
                bad(f"id {int(ids[k])} at index {k} is out of range 0..{self.n - 1}", name)
        if not np.all(np.isfinite(self.z)):
            k = int(np.flatnonzero(~np.all(np.isfinite(self.z), axis=1))[0])
            bad(f"non-finite value in row {k}", "z")
        reach = np.abs(self.z).max(axis=1) if self.z.size else np.zeros(0)
        if np.any(reach > MAX_REACH * self.radius):
            k = int(np.flatnonzero(reach > MAX_REACH * self.radius)[0])
            bad(f"row {k} lies {reach[k]:.3g} from the module centre, beyond {MAX_REACH:g} radii: an observation "
                "is a point on the observer's perimeter (about one radius away)", "z")
        if np.any(self.i == self.j):
            k = int(np.flatnonzero(self.i == self.j)[0])
            bad(f"module {int(self.i[k])} observes itself at index {k}", "j")
        key = self.i * self.n + self.j
        if np.unique(key).size != key.size:
            bad("an observation (i, j) appears more than once", "i")
        rev = np.sort(self.j * self.n + self.i)
        missing = ~np.isin(key, rev, assume_unique=True)
        if np.any(missing):
            k = int(np.flatnonzero(missing)[0])
            bad(f"observation ({int(self.i[k])}, {int(self.j[k])}) has no reverse ({int(self.j[k])}, "
                f"{int(self.i[k])}): observations must come in symmetric pairs", "j")

    # ------------------------------------------------------------------ graph views
    @property
    def num_observations(self) -> int:
        """Number of directed observations E."""
        return int(self.i.shape[0])

    def adjacency(self) -> sparse.csr_matrix:
        """Symmetric 0/1 contact graph (n, n) in CSR form: 1 where an observation pair exists.

        Relies on the contract's symmetric pairs (checked by :meth:`validate`).
        """
        if "adj" not in self._cache:
            a = sparse.csr_matrix((np.ones(self.i.size), (self.i, self.j)), shape=(self.n, self.n))
            a.sort_indices()
            self._cache["adj"] = a
        return self._cache["adj"]

    def pairs(self) -> np.ndarray:
        """Undirected contact pairs (P, 2) with ``pairs[:, 0] < pairs[:, 1]``, each once."""
        if "pairs" not in self._cache:
            a = sparse.triu(self.adjacency(), k=1).tocoo()
            self._cache["pairs"] = np.stack([a.row, a.col], 1).astype(np.int64)
        return self._cache["pairs"]

    def subproblem(self, nodes: np.ndarray) -> "EnsembleProblem":
        """The problem restricted to modules ``nodes`` (relabelled 0..len(nodes)-1 in that order).

        Keeps the observations with both ends in ``nodes`` (G_V in Algorithm 1 of Funiak et al. 2008).
        """
        nodes = np.asarray(nodes, dtype=np.int64)
        index = np.full(self.n, -1, dtype=np.int64)
        index[nodes] = np.arange(nodes.size)
        keep = (index[self.i] >= 0) & (index[self.j] >= 0)
        return EnsembleProblem(self.dim, int(nodes.size), self.radius, index[self.i[keep]],
                               index[self.j[keep]], self.z[keep])


def connected_components(adjacency: sparse.spmatrix) -> tuple[int, np.ndarray]:
    """Number of connected components and a label (n,) per node of a symmetric sparse graph."""
    from scipy.sparse.csgraph import connected_components as cc

    k, labels = cc(adjacency, directed=False)
    return int(k), labels.astype(np.int64)


@dataclass(frozen=True)
class EnsembleEstimate:
    """One pose per module in one arbitrary global frame.

    Attributes
    ----------
    position : ndarray, shape (n, dim)
        Module centres (metres).
    rotation : ndarray, shape (n, dim, dim)
        Module orientations as matrices mapping local to global vectors.
    component : ndarray of int, shape (n,)
        Connected component of the contact graph each module belongs to; modules of different
        components have no observation linking them, so their relative pose is not estimated
        (components are laid side by side, never overlapping).
    """

    position: np.ndarray
    rotation: np.ndarray
    component: np.ndarray

    @property
    def dim(self) -> int:
        """Dimension (2 or 3)."""
        return int(self.position.shape[1])

    @property
    def orientation(self) -> np.ndarray:
        """Contract form: angles (n,) in 2D, unit quaternions (n, 4) = (w, x, y, z) in 3D."""
        if self.dim == 2:
            return matrix_to_angle(self.rotation)
        return matrix_to_quat(self.rotation)

    @staticmethod
    def orientation_to_matrix(orientation: np.ndarray, dim: int) -> np.ndarray:
        """Matrices (n, dim, dim) from contract-form orientations (angles or quaternions)."""
        return angle_to_matrix(orientation) if dim == 2 else quat_to_matrix(orientation)
