"""Fixtures for the ensemble tests: noiseless and noisy lattices under the contract's model.

An observation z_ij lies on module i's perimeter, in i's local frame, pointing to j (Funiak et al. 2008
§III-A, docs/formats.md); in a noiseless lattice it is exactly R_i^T (c_j - c_i) / 2.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from decentral.ensemble.problem import EnsembleProblem
from decentral.ensemble.rotation import angle_to_matrix, so3_exp


def make_lattice(dim: int, shape: tuple, *, radius: float = 0.05, noise: float = 0.0, seed: int = 0,
                 hexagonal: bool = True):
    """Return (problem, true centres (n, d), true rotations (n, d, d)) of a lattice ensemble.

    ``noise`` is the standard deviation of the observation direction error in module radii.
    """
    rng = np.random.default_rng(seed)
    if dim == 2:
        a, b = np.meshgrid(np.arange(shape[0]), np.arange(shape[1]), indexing="ij")
        a, b = a.ravel(), b.ravel()
        if hexagonal:
            x = np.stack([a + 0.5 * (b % 2), b * np.sqrt(3) / 2], 1) * 2 * radius
        else:
            x = np.stack([a, b], 1) * 2.0 * radius
        R = angle_to_matrix(rng.uniform(-np.pi, np.pi, len(x)))
    else:
        g = np.stack(np.meshgrid(*[np.arange(k) for k in shape], indexing="ij"), -1).reshape(-1, 3)
        x = g * 2.0 * radius
        R = so3_exp(rng.normal(size=(len(x), 3)))
    pairs = cKDTree(x).query_pairs(2 * radius * 1.01, output_type="ndarray")
    i = np.concatenate([pairs[:, 0], pairs[:, 1]])
    j = np.concatenate([pairs[:, 1], pairs[:, 0]])
    z = np.einsum("eba,eb->ea", R[i], (x[j] - x[i]) / 2)
    if noise:
        z = z + noise * radius * rng.normal(size=z.shape)
        z = z / np.linalg.norm(z, axis=1, keepdims=True) * radius
    return EnsembleProblem.create(dim, len(x), radius, i, j, z), x, R


@pytest.fixture
def lattice():
    """The :func:`make_lattice` factory."""
    return make_lattice
