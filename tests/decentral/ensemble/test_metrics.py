"""Tests of the §VI-C accuracy metrics (global and local RMS in module radii)."""

import numpy as np

from decentral.ensemble.metrics import evaluate, local_regions
from decentral.ensemble.rotation import angle_to_matrix


def test_similarity_transformed_truth_has_zero_error(lattice):
    """A scaled, rotated and shifted copy of the truth has zero global and local RMS."""
    prob, x, _ = lattice(2, (8, 8))
    est = 1.7 * x @ angle_to_matrix(0.8).T + np.array([3.0, -1.0])
    err = evaluate(est, x, prob.pairs(), prob.radius)
    assert err.global_rms < 1e-10 and err.local_rms < 1e-10
    assert np.isclose(err.scale, 1 / 1.7)


def test_bent_estimate_has_small_local_but_large_global_error(lattice):
    """Bending a long strip is a large global error but a small error relative to neighbours."""
    prob, x, _ = lattice(2, (40, 4))
    L = x[:, 0].max()
    phi = 0.8 * x[:, 0] / L  # bend the strip into an arc
    radius_of_arc = L / 0.8
    est = np.stack([(radius_of_arc - x[:, 1]) * np.sin(phi), radius_of_arc - (radius_of_arc - x[:, 1]) * np.cos(phi)], 1)
    err = evaluate(est, x, prob.pairs(), prob.radius)
    assert err.global_rms > 5 * err.local_rms
    assert err.global_rms > 1.0


def test_regions_are_connected_and_small(lattice):
    """Every local region is within six module diameters across in the true layout."""
    prob, x, _ = lattice(2, (15, 15))
    lab = local_regions(x, prob.adjacency(), prob.radius, 6.0)
    assert lab.min() == 0
    for r in range(lab.max() + 1):
        pts = x[lab == r]
        span = np.linalg.norm(pts[:, None] - pts[None], axis=2).max()
        assert span <= 12 * prob.radius + 1e-9
