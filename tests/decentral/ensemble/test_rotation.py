"""Tests of the batched rotation helpers (the nearest-rotation projection used by every Kabsch fit)."""

import numpy as np
import pytest

from decentral.ensemble.rotation import _project_svd, project_to_rotation


@pytest.mark.parametrize("dim", [2, 3])
def test_projection_matches_the_svd_solution(dim):
    """The fast projection (closed form in 2D, Newton polar iteration in 3D) equals the SVD one."""
    M = np.random.default_rng(0).normal(size=(500, dim, dim))
    assert np.allclose(project_to_rotation(M), _project_svd(M), atol=1e-10)


@pytest.mark.parametrize("dim", [2, 3])
def test_projection_of_degenerate_matrices_is_a_best_rotation(dim):
    """Zero, rank-deficient and reflected matrices still give proper rotations maximizing tr(R^T M)."""
    rng = np.random.default_rng(1)
    M = rng.normal(size=(60, dim, dim))
    M[:10] = 0.0
    M[10:20, :, -1] = 0.0  # rank deficient
    M[20:30, :, 0] *= -1.0  # reflected
    R = project_to_rotation(M)
    assert np.allclose(np.einsum("nab,nac->nbc", R, R), np.eye(dim), atol=1e-12)
    assert np.allclose(np.linalg.det(R), 1.0)
    best = np.einsum("nab,nab->n", _project_svd(M), M)
    assert np.all(np.einsum("nab,nab->n", R, M) >= best - 1e-10)
