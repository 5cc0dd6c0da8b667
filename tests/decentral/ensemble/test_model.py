"""Tests of the observation model, likelihood and gradients (Funiak et al. 2008 eq. 1-3)."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from decentral.ensemble.model import (
    fit_orientations,
    gradient,
    negative_log_likelihood,
    positions_given_rotations,
    residuals,
)
from decentral.ensemble.problem import EnsembleProblem
from decentral.ensemble.rotation import angle_to_matrix, matrix_to_angle, matrix_to_quat, quat_to_matrix


def _random_problem(rng, dim, n=6):
    i, j = [], []
    for a in range(n):
        for b in range(a + 1, n):
            if rng.random() < 0.6 or b == a + 1:
                i += [a, b]
                j += [b, a]
    z = rng.normal(size=(len(i), dim))
    return EnsembleProblem.create(dim, n, 1.0, i, j, z)


def test_residuals_vanish_at_truth_2d(lattice):
    """On a noiseless planar lattice every residual is zero at the true poses."""
    prob, x, R = lattice(2, (5, 4))
    assert np.abs(residuals(prob, x, matrix_to_angle(R))).max() < 1e-12


def test_residuals_vanish_at_truth_3d(lattice):
    """On a noiseless cubic lattice every residual is zero at the true poses (quaternions)."""
    prob, x, R = lattice(3, (3, 3, 3))
    assert np.abs(residuals(prob, x, matrix_to_quat(R))).max() < 1e-12


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_gradient_matches_finite_differences_2d(seed):
    """The analytic 2D gradient (centres and angles) equals central finite differences."""
    rng = np.random.default_rng(seed)
    prob = _random_problem(rng, 2)
    c = rng.normal(size=(prob.n, 2))
    th = rng.uniform(-np.pi, np.pi, prob.n)
    gc, gt = gradient(prob, c, th)
    h = 1e-6
    num_c = np.zeros_like(c)
    for k in range(prob.n):
        for a in range(2):
            e = np.zeros_like(c)
            e[k, a] = h
            num_c[k, a] = (negative_log_likelihood(prob, c + e, th) - negative_log_likelihood(prob, c - e, th)) / (2 * h)
    num_t = np.array([(negative_log_likelihood(prob, c, th + h * np.eye(prob.n)[k])
                       - negative_log_likelihood(prob, c, th - h * np.eye(prob.n)[k])) / (2 * h) for k in range(prob.n)])
    np.testing.assert_allclose(gc, num_c, atol=1e-6)
    np.testing.assert_allclose(gt, num_t, atol=1e-6)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1), st.floats(0.3, 3.0))
def test_gradient_matches_finite_differences_3d_unnormalized_quaternion(seed, qscale):
    """The analytic 3D gradient w.r.t. centres and unnormalized quaternions equals finite differences."""
    rng = np.random.default_rng(seed)
    prob = _random_problem(rng, 3)
    c = rng.normal(size=(prob.n, 3))
    q = rng.normal(size=(prob.n, 4))
    q = qscale * q / np.linalg.norm(q, axis=1, keepdims=True)
    gc, gq = gradient(prob, c, q)
    h = 1e-6
    num_q = np.zeros_like(q)
    for k in range(prob.n):
        for a in range(4):
            e = np.zeros_like(q)
            e[k, a] = h
            num_q[k, a] = (negative_log_likelihood(prob, c, q + e) - negative_log_likelihood(prob, c, q - e)) / (2 * h)
    num_c = np.zeros_like(c)
    for k in range(prob.n):
        for a in range(3):
            e = np.zeros_like(c)
            e[k, a] = h
            num_c[k, a] = (negative_log_likelihood(prob, c + e, q) - negative_log_likelihood(prob, c - e, q)) / (2 * h)
    np.testing.assert_allclose(gq, num_q, atol=2e-5, rtol=1e-5)
    np.testing.assert_allclose(gc, num_c, atol=1e-6)


def test_quaternion_gradient_is_orthogonal_to_scaling():
    """Implicit normalization makes the likelihood scale-invariant in q, so grad_q . q = 0."""
    rng = np.random.default_rng(3)
    prob = _random_problem(rng, 3)
    q = rng.normal(size=(prob.n, 4))
    _, gq = gradient(prob, rng.normal(size=(prob.n, 3)), q)
    np.testing.assert_allclose(np.einsum("na,na->n", gq, q), 0.0, atol=1e-9)


def test_fit_orientations_recovers_truth(lattice):
    """Given the true centres, the closed-form per-module fit returns the true orientations."""
    prob, x, R = lattice(3, (3, 3, 2))
    np.testing.assert_allclose(fit_orientations(prob, x), R, atol=1e-10)


def test_positions_given_rotations_recovers_truth(lattice):
    """Given the true orientations, the Laplacian solve returns the true centres up to translation."""
    prob, x, R = lattice(2, (6, 5))
    c = positions_given_rotations(prob, R)
    np.testing.assert_allclose(c - c[0], x - x[0], atol=1e-10)


def test_quaternion_round_trip():
    """matrix_to_quat inverts quat_to_matrix (up to the sign of q)."""
    rng = np.random.default_rng(0)
    q = rng.normal(size=(50, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 0] < 0] *= -1
    np.testing.assert_allclose(matrix_to_quat(quat_to_matrix(q)), q, atol=1e-12)


def test_angle_round_trip():
    """matrix_to_angle inverts angle_to_matrix on (-pi, pi]."""
    th = np.linspace(-3.1, 3.1, 17)
    np.testing.assert_allclose(matrix_to_angle(angle_to_matrix(th)), th, atol=1e-12)
