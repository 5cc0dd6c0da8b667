"""Make an ensemble (module poses + IR observations) and save it as ``decentral.ensemble/1`` plus truth.

:func:`generate` turns an :class:`EnsembleSpec` and a random generator into an :class:`Ensemble`:
2D shapes are filled by settling modules under gravity (:mod:`sims.simulation.ensembles.settle`), 3D shapes are
rasterized into a lattice (:mod:`sims.simulation.ensembles.lattices`); orientations are uniformly random; the
observations come from the IR model of :mod:`sims.simulation.ensembles.sensors`. Modules outside the largest
connected group of the observation graph cannot be localized relative to the rest, so they are dropped
(and counted) and the survivors renumbered 0..n-1.

Files (both written atomically, ``np.load(..., allow_pickle=False)`` reads them):

- observations, docs/formats.md: ``format`` = ``decentral.ensemble/1``, ``dim``, ``n``, ``radius``,
  ``i``, ``j`` (E ints), ``z`` (E x dim);
- truth: ``format`` = ``decentral.ensemble_truth/1``, ``dim``, ``n``, ``radius``, ``position``
  (n x dim), ``orientation`` (n angles, or n x 4 unit quaternions w, x, y, z: module frame to world),
  ``shape``, ``seed`` (-1 when unknown), ``dropped``.
"""

from __future__ import annotations

import io
import os
from dataclasses import dataclass, field

import numpy as np
from scipy import sparse
from scipy.sparse.csgraph import connected_components

from decentral.errors import InputError
from sims.simulation.ensembles.containers import SHAPES_2D, make_container
from sims.simulation.ensembles.lattices import LATTICES, SHAPES_3D, rasterize
from sims.simulation.ensembles.sensors import SensorModel, observe_contacts
from sims.simulation.ensembles.settle import settle
from sims.io.atomic import write_atomic
from sims.io.ensemble_npz import OBSERVATION_FORMAT, TRUTH_FORMAT

__all__ = [
    "EnsembleSpec",
    "Ensemble",
    "SHAPES",
    "OBSERVATION_FORMAT",
    "TRUTH_FORMAT",
    "generate",
    "save_observations",
    "save_truth",
]


#: every shape name -> its dimension
SHAPES: dict[str, int] = {**{k: 2 for k in SHAPES_2D}, **{k: 3 for k in SHAPES_3D}}


@dataclass(frozen=True)
class EnsembleSpec:
    """What ensemble to make.

    Attributes
    ----------
    shape : str
        A 2D container (``triple``, ``sparse``, ``open``, ``funnel``, ``ring``, ``blobs``) or a 3D
        solid (``sphere``, ``box``, ``torus``, ``dumbbell``, ``triple3d``).
    n : int
        Number of modules requested (a few may be dropped, see :class:`Ensemble`).
    radius : float
        Module radius (metres).
    lattice : str
        3D only: ``hcp`` or ``cubic``.
    jitter : float
        3D only: standard deviation of the lattice jitter, in module radii.
    sensors : SensorModel
        The IR transceiver model.
    """

    shape: str = "triple"
    n: int = 1000
    radius: float = 0.05
    lattice: str = "hcp"
    jitter: float = 0.03
    sensors: SensorModel = field(default_factory=SensorModel)

    def __post_init__(self):
        if self.shape not in SHAPES:
            raise InputError(f"unknown shape {self.shape!r} (known: {', '.join(SHAPES)})", field="shape")
        if int(self.n) != self.n or self.n < 2:
            raise InputError("need at least 2 modules", field="n")
        if not (np.isfinite(self.radius) and self.radius > 0):
            raise InputError("module radius must be positive", field="radius")
        if self.lattice not in LATTICES:
            raise InputError(f"unknown lattice {self.lattice!r}", field="lattice")
        if not (0 <= self.jitter < 0.5):
            raise InputError("jitter must be in [0, 0.5) module radii", field="jitter")

    @property
    def dim(self) -> int:
        """2 or 3, from the shape."""
        return SHAPES[self.shape]


@dataclass(frozen=True)
class Ensemble:
    """A generated ensemble: ground truth and the observations its modules make.

    Attributes
    ----------
    spec : EnsembleSpec
        What was asked for.
    position : ndarray, shape (n, dim)
        True module centres (world frame, metres; y up in 2D, z up in 3D).
    orientation : ndarray, shape (n,) or (n, 4)
        True orientations, module frame to world: angles in 2D, unit quaternions (w, x, y, z) in 3D.
    i, j : ndarray of int64, shape (E,)
        Observation pairs, symmetric.
    z : ndarray, shape (E, dim)
        z_{i,j}: sensor of i that saw j, on the perimeter, in i's local frame (Funiak et al. 2008 Fig. 2b).
    dropped : int
        Modules removed because they were not connected to the largest observation component.
    """

    spec: EnsembleSpec
    position: np.ndarray
    orientation: np.ndarray
    i: np.ndarray
    j: np.ndarray
    z: np.ndarray
    dropped: int

    @property
    def n(self) -> int:
        """Number of modules."""
        return len(self.position)

    @property
    def dim(self) -> int:
        """2 or 3."""
        return self.position.shape[1]

    @property
    def radius(self) -> float:
        """Module radius."""
        return self.spec.radius


def _random_orientation(n: int, dim: int, rng: np.random.Generator) -> np.ndarray:
    if dim == 2:
        return rng.uniform(-np.pi, np.pi, size=n)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 0] < 0] *= -1.0  # one hemisphere: w >= 0
    return q


def generate(spec: EnsembleSpec, rng: np.random.Generator) -> Ensemble:
    """Build the ensemble described by ``spec``.

    Placement, orientations and nothing else draw from separate child streams of ``rng``, so
    changing e.g. the sensor model leaves the geometry unchanged.
    """
    place_rng, orient_rng = rng.spawn(2)
    if spec.dim == 2:
        container = make_container(spec.shape, spec.n, spec.radius, place_rng)
        position = settle(container, spec.n, spec.radius, place_rng).position
    else:
        position = rasterize(spec.shape, spec.n, spec.radius, spec.lattice, spec.jitter, place_rng)
    orientation = _random_orientation(spec.n, spec.dim, orient_rng)
    i, j, z = observe_contacts(position, orientation, spec.radius, spec.sensors)
    adj = sparse.coo_matrix((np.ones(len(i)), (i, j)), shape=(spec.n, spec.n)).tocsr()
    count, label = connected_components(adj, directed=False)
    dropped = 0
    if count > 1:
        keep = label == np.argmax(np.bincount(label))
        dropped = int(spec.n - keep.sum())
        new_id = np.cumsum(keep) - 1
        edge = keep[i]  # both ends share a component
        i, j, z = new_id[i[edge]], new_id[j[edge]], z[edge]
        position, orientation = position[keep], orientation[keep]
    return Ensemble(spec, position, orientation, i.astype(np.int64), j.astype(np.int64), z, dropped)


def _save_npz(path: str | os.PathLike, arrays: dict) -> None:
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    write_atomic(path, lambda fh: fh.write(buf.getvalue()), binary=True)


def save_observations(path: str | os.PathLike, ens: Ensemble) -> None:
    """Write the observations as ``decentral.ensemble/1`` (docs/formats.md), atomically."""
    _save_npz(
        path,
        {
            "format": np.array(OBSERVATION_FORMAT),
            "dim": np.array(ens.dim, dtype=np.int64),
            "n": np.array(ens.n, dtype=np.int64),
            "radius": np.array(ens.radius, dtype=np.float64),
            "i": ens.i,
            "j": ens.j,
            "z": ens.z.astype(np.float64),
        },
    )


def save_truth(path: str | os.PathLike, ens: Ensemble, seed: int | None = None) -> None:
    """Write the true poses as ``decentral.ensemble_truth/1``, atomically."""
    _save_npz(
        path,
        {
            "format": np.array(TRUTH_FORMAT),
            "dim": np.array(ens.dim, dtype=np.int64),
            "n": np.array(ens.n, dtype=np.int64),
            "radius": np.array(ens.radius, dtype=np.float64),
            "position": ens.position.astype(np.float64),
            "orientation": ens.orientation.astype(np.float64),
            "shape": np.array(ens.spec.shape),
            "seed": np.array(-1 if seed is None else int(seed), dtype=np.int64),
            "dropped": np.array(ens.dropped, dtype=np.int64),
            # observed neighbour pairs (P, 2), i < j: what `decentral score` scales and regions by
            "pairs": np.unique(np.sort(np.stack([ens.i, ens.j], 1), axis=1), axis=0).reshape(-1, 2),
        },
    )
