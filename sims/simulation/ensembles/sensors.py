"""The infrared contact sensor model of Funiak et al. 2008 §VI: which module pairs see each other, and with which sensors.

Every module carries transceivers (colocated emitter/detector pairs) pointing radially outwards: 12
evenly spaced on the perimeter in 2D, 50 scattered (a Fibonacci spiral) over the sphere in 3D. A
transceiver sits ``depth`` below the surface. The signal from emitter e of module i to receiver r of
module j falls off with the inverse square of their distance and with the cosine of the angle of each
to the line joining them (Lambertian lobes):

.. math::  I_{e,r} = \\frac{\\cos^+ \\alpha_e \\, \\cos^+ \\alpha_r}{\\|p_r - p_e\\|^2}

The peak intensity is that of two touching modules with facing transceivers, ``1 / (2 depth)^2``. A
pair is observed when its strongest transceiver pair reaches ``threshold`` (20 %) of the peak, so
modules are seen a little before they touch and the reported sensor positions are quantized to the
transceiver layout. The observation z_{i,j} is module i's transceiver of that strongest pair, moved to
the perimeter and written in i's local frame (Funiak et al. 2008 §III-A, Fig. 2b); the pair gives z_{j,i} from
module j's transceiver, so observations are symmetric by construction. Occlusion is not modelled: only
pairs within sensing range of each other are candidates, and at that range a third module cannot sit
between them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["SensorModel", "sensor_layout", "observe_contacts", "rotation_matrices"]


@dataclass(frozen=True)
class SensorModel:
    """Parameters of the IR transceiver model.

    Attributes
    ----------
    count : int or None
        Transceivers per module; ``None`` means 12 in 2D and 50 in 3D (Funiak et al. 2008 §VI).
    depth : float
        Recess of each transceiver below the surface, in module radii.
    threshold : float
        Detection threshold as a fraction of the peak intensity (Funiak et al. 2008 §VI: 0.2).
    lobe : float
        Exponent of the cosine lobe of emitters and receivers.
    """

    count: int | None = None
    depth: float = 0.2
    threshold: float = 0.2
    lobe: float = 1.0

    def transceivers(self, dim: int) -> int:
        """Transceivers per module in dimension ``dim``."""
        return self.count if self.count is not None else (12 if dim == 2 else 50)

    def reach(self, radius: float) -> float:
        """Largest centre distance at which any pair can be detected (facing transceivers)."""
        d = self.depth * radius
        return 2.0 * (radius - d) + 2.0 * d / np.sqrt(self.threshold)


def sensor_layout(dim: int, count: int) -> np.ndarray:
    """Unit transceiver directions (count, dim) in the module frame: even in 2D, Fibonacci in 3D."""
    k = np.arange(count)
    if dim == 2:
        a = 2.0 * np.pi * k / count
        return np.column_stack([np.cos(a), np.sin(a)])
    z = 1.0 - (2.0 * k + 1.0) / count
    rho = np.sqrt(1.0 - z**2)
    phi = k * np.pi * (3.0 - np.sqrt(5.0))
    return np.column_stack([rho * np.cos(phi), rho * np.sin(phi), z])


def rotation_matrices(orientation: np.ndarray) -> np.ndarray:
    """Rotation matrices (n, d, d) from angles (n,) in 2D or unit quaternions (n, 4) w, x, y, z in 3D."""
    if orientation.ndim == 1:
        c, s = np.cos(orientation), np.sin(orientation)
        return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)
    w, x, y, z = orientation.T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def _candidates(layout: np.ndarray, local_dirs: np.ndarray, k: int) -> np.ndarray:
    """Indices (m, k) of the ``k`` transceivers nearest in angle to each local direction (m, d)."""
    if layout.shape[1] == 2:
        step = 2.0 * np.pi / len(layout)
        nearest = np.rint(np.arctan2(local_dirs[:, 1], local_dirs[:, 0]) / step).astype(np.intp)
        offsets = np.arange(k) - (k - 1) // 2
        return (nearest[:, None] + offsets[None, :]) % len(layout)
    _, idx = cKDTree(layout).query(local_dirs, k=k)
    return idx


def observe_contacts(
    position: np.ndarray,
    orientation: np.ndarray,
    radius: float,
    model: SensorModel = SensorModel(),
    *,
    candidates: int = 4,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Simulate the IR observations of an ensemble.

    Parameters
    ----------
    position : ndarray, shape (n, d)
        Module centres in the world frame.
    orientation : ndarray, shape (n,) or (n, 4)
        Module orientations: angles in 2D, unit quaternions (w, x, y, z) in 3D (module frame to world).
    radius : float
        Module radius.
    model : SensorModel
        Transceiver layout and detection parameters.
    candidates : int
        Transceivers per module tried for each pair: those nearest in angle to the other module
        (3 in 2D already span +-45 degrees; farther ones are weaker on both counts).

    Returns
    -------
    i, j : ndarray of int, shape (E,)
        Observing and observed module; both (i, j) and (j, i) are present.
    z : ndarray, shape (E, d)
        z_{i,j}: the observing transceiver of i, on the perimeter, in i's local frame.
    """
    n, dim = position.shape
    layout = sensor_layout(dim, model.transceivers(dim))
    pairs = cKDTree(position).query_pairs(model.reach(radius) * (1 + 1e-9), output_type="ndarray")
    if len(pairs) == 0:
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty, np.zeros((0, dim))
    a, b = pairs[:, 0], pairs[:, 1]
    R = rotation_matrices(orientation)
    d = position[b] - position[a]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    k = min(candidates if dim == 3 else 3, len(layout))
    ca = _candidates(layout, np.einsum("mji,mj->mi", R[a], d), k)  # R^T d: direction to b in a's frame
    cb = _candidates(layout, np.einsum("mji,mj->mi", R[b], -d), k)
    inner = radius * (1.0 - model.depth)
    axis_a = np.einsum("mij,mkj->mki", R[a], layout[ca])  # (m, k, d) world axes of a's candidates
    axis_b = np.einsum("mij,mkj->mki", R[b], layout[cb])
    pa = position[a][:, None, :] + inner * axis_a
    pb = position[b][:, None, :] + inner * axis_b
    v = pb[:, None, :, :] - pa[:, :, None, :]  # (m, k_a, k_b, d) emitter of a -> receiver of b
    dist2 = np.maximum(np.einsum("mpqd,mpqd->mpq", v, v), 1e-30)
    dist = np.sqrt(dist2)
    cos_a = np.einsum("mpd,mpqd->mpq", axis_a, v) / dist
    cos_b = -np.einsum("mqd,mpqd->mpq", axis_b, v) / dist
    intensity = (np.clip(cos_a, 0, None) * np.clip(cos_b, 0, None)) ** model.lobe / dist2
    flat = intensity.reshape(len(a), -1)
    best = np.argmax(flat, axis=1)
    peak = 1.0 / (2.0 * model.depth * radius) ** 2
    seen = flat[np.arange(len(a)), best] >= model.threshold * peak
    ka, kb = np.unravel_index(best[seen], (k, k))
    sa, sb = ca[seen, ka], cb[seen, kb]
    a, b = a[seen], b[seen]
    i = np.concatenate([a, b]).astype(np.int64)
    j = np.concatenate([b, a]).astype(np.int64)
    z = radius * np.concatenate([layout[sa], layout[sb]])
    order = np.lexsort((j, i))
    return i[order], j[order], z[order]
