"""Tests of the two-level initial inverse Hessian (rigid motions of clusters) of the L-BFGS refiner."""

import numpy as np
import pytest

from decentral.ensemble.coarse import TwoLevelInverse, cluster_labels
from decentral.ensemble.model import gradient, negative_log_likelihood
from decentral.ensemble.refine import LaplacianSolver, RefineConfig, refine
from decentral.ensemble.sparse_ops import Incidence
from decentral.ensemble.rotation import angle_to_matrix, matrix_to_angle, matrix_to_quat, so3_exp


def _operator(prob, x, R, labels, fixed=None, every_centre_free=False):
    """TwoLevelInverse at (x, R) (radius 1, so radii = metres) with the Laplacian of the contact graph; the
    Laplacian holds one centre (the gauge) unless ``every_centre_free`` (for checks of the coarse space alone)."""
    lap = LaplacianSolver(prob.n, prob.i, prob.j, fixed=fixed)
    free = np.ones(prob.n, bool) if every_centre_free else lap.free

    def fine(v):
        out = np.zeros_like(v)
        out[lap.free] = 4.0 * lap.solve_reduced(v[lap.free])
        return out

    turned = np.einsum("eab,eb->ea", R[prob.i], prob.z)
    turning = np.ones(prob.n, bool) if fixed is None else ~fixed
    return TwoLevelInverse(prob.i, prob.j, Incidence(prob.n, prob.i, prob.j).B, x, turned, labels, free, turning, fine), lap


def _move(x, R, labels, delta, dim):
    """Cluster rigid motions (t_k, w_k) applied exactly: centres turned about each cluster's centroid."""
    k = labels.max() + 1
    m = 3 if dim == 2 else 6
    delta = delta.reshape(k, m)
    g = np.stack([x[labels == c].mean(0) for c in range(k)])
    Q = angle_to_matrix(delta[:, 2]) if dim == 2 else so3_exp(delta[:, 3:])
    t = delta[:, :dim]
    return g[labels] + np.einsum("nab,nb->na", Q[labels], x - g[labels]) + t[labels], Q[labels] @ R


def _orientation(prob, R):
    """The model's orientation parameters (angles in 2D, quaternions in 3D) of matrices R (n, d, d)."""
    return matrix_to_angle(R) if prob.dim == 2 else matrix_to_quat(R)


def _position_gradient(prob, x, R):
    """d cost / d c (n, d) at fixed orientations, from the model's analytic gradient."""
    return gradient(prob, x, _orientation(prob, R))[0]


def _cost(prob, x, R):
    return negative_log_likelihood(prob, x, _orientation(prob, R))


def test_cluster_labels_use_every_cluster_and_repeat(lattice):
    """A k-way partition into about n / size clusters, each non-empty, the same on every call."""
    prob, _, _ = lattice(3, (8, 6, 5))
    a = cluster_labels(prob.adjacency(), 40)
    assert a.shape == (prob.n,)
    assert set(np.unique(a)) == set(range(round(prob.n / 40)))
    assert np.array_equal(a, cluster_labels(prob.adjacency(), 40))
    assert np.all(cluster_labels(prob.adjacency(), 10_000) == 0)


@pytest.mark.parametrize("dim,shape", [(2, (12, 10)), (3, (6, 5, 4))])
def test_coarse_curvature_is_the_hessian_of_rigid_cluster_motions(lattice, dim, shape):
    """On a noiseless ensemble (zero residuals, so Gauss-Newton is exact) d^T E d is the second
    derivative of the likelihood along the cluster rigid motions d, orientations turning with them,
    and G d the first derivative of the position gradient."""
    prob, x, R = lattice(dim, shape, radius=1.0)
    labels = cluster_labels(prob.adjacency(), 20)
    op, _ = _operator(prob, x, R, labels, every_centre_free=True)
    rng = np.random.default_rng(4)
    h = 1e-4
    for _ in range(3):
        d = rng.normal(size=op.curvature.shape[0])
        second = (_cost(prob, *_move(x, R, labels, h * d, dim)) + _cost(prob, *_move(x, R, labels, -h * d, dim))
                  - 2 * _cost(prob, x, R)) / h**2
        assert np.isclose(d @ op.curvature @ d, second, rtol=1e-5)
        # G d is the first-order change of the position gradient -B^T r under the motions
        np.testing.assert_allclose((op.G @ d).reshape(x.shape),
                                   (_position_gradient(prob, *_move(x, R, labels, h * d, dim))
                                    - _position_gradient(prob, *_move(x, R, labels, -h * d, dim))) / (2 * h),
                                   atol=1e-6)
        # and P is their first-order centre displacement (central difference)
        ahead, _ = _move(x, R, labels, h * d, dim)
        behind, _ = _move(x, R, labels, -h * d, dim)
        np.testing.assert_allclose((op.P @ d).reshape(x.shape), (ahead - behind) / (2 * h), atol=1e-6)


@pytest.mark.parametrize("dim,shape", [(2, (12, 10)), (3, (6, 5, 4))])
def test_two_level_inverse_is_symmetric_positive_definite_on_the_free_centres(lattice, dim, shape):
    """u^T H0 v = v^T H0 u, v^T H0 v > 0 for v != 0, and H0 never moves a held centre."""
    prob, x, R = lattice(dim, shape, noise=0.2, seed=1, radius=1.0)
    fixed = np.zeros(prob.n, bool)
    fixed[:7] = True
    op, lap = _operator(prob, x, R, cluster_labels(prob.adjacency(), 15), fixed)
    rng = np.random.default_rng(2)
    u, v = rng.normal(size=(2,) + x.shape)
    u[~lap.free] = v[~lap.free] = 0.0
    assert np.isclose(np.vdot(u, op(v)), np.vdot(v, op(u)), rtol=1e-10)
    assert np.vdot(v, op(v)) > 0 and np.vdot(u, op(u)) > 0
    assert np.all(op(v)[~lap.free] == 0.0)


def _twisted_bar(lattice, shape, twist):
    """A noisy 3D bar started twisted about its long axis by ``twist`` radians end to end, orientations turned
    with it: the soft mode that the Laplacian alone relaxes slowly."""
    prob, x, R = lattice(3, shape, radius=1.0, noise=0.05, seed=2)
    angle = twist * (x[:, 0] - x[:, 0].min()) / np.ptp(x[:, 0])
    Q = so3_exp(np.stack([angle, 0 * angle, 0 * angle], 1))
    g = x.mean(0)
    return prob, g + np.einsum("nab,nb->na", Q, x - g), Q @ R


@pytest.mark.parametrize("shape,twist", [((24, 4, 4), 0.6), ((40, 3, 3), 0.8)])
def test_coarse_space_relaxes_a_twist_in_half_the_iterations_to_the_same_optimum(lattice, shape, twist):
    """From a twisted start, L-BFGS with the cluster motions reaches the same maximum likelihood as with
    4 L^-1 alone in at most half as many iterations (measured 70 -> 31 and 175 -> 56)."""
    prob, x0, R0 = _twisted_bar(lattice, shape, twist)
    base = RefineConfig(method="lbfgs", history=30, max_iter=2000, gtol=1e-8, ftol=0.0)
    plain = refine(prob, x0, R0, base)
    two_level = refine(prob, x0, R0, RefineConfig(**{**base.__dict__, "coarse_size": 32}))
    assert plain.status == two_level.status == "converged"
    assert np.isclose(two_level.cost, plain.cost, rtol=1e-10)
    assert two_level.iterations <= plain.iterations / 2


def test_coarse_space_with_held_modules_keeps_them(lattice):
    """A seam-style refinement with held modules and the coarse space leaves the held poses untouched."""
    prob, x, R = lattice(3, (8, 5, 4), noise=0.2, seed=6)
    fixed = np.zeros(prob.n, bool)
    fixed[::5] = True
    res = refine(prob, x, R, RefineConfig(method="lbfgs", history=30, gtol=1e-9, max_iter=500, coarse_size=20),
                 fixed=fixed)
    assert res.status == "converged"
    np.testing.assert_array_equal(res.position[fixed], x[fixed])
    np.testing.assert_array_equal(res.rotation[fixed], R[fixed])


def test_negative_coarse_size_is_refused(lattice):
    """A negative cluster size is a configuration error, not a silent "off"."""
    prob, x, R = lattice(2, (6, 6))
    with pytest.raises(ValueError, match="coarse_size"):
        refine(prob, x, R, RefineConfig(method="lbfgs", coarse_size=-1))


def test_coarse_space_is_skipped_below_two_clusters(lattice):
    """Below twice the cluster size the refiner runs 4 L^-1 alone: the same iterates as coarse_size=0."""
    prob, x, R = lattice(2, (8, 8), noise=0.2, seed=2)
    a = refine(prob, x, R, RefineConfig(method="lbfgs", history=30, gtol=1e-9, coarse_size=0))
    b = refine(prob, x, R, RefineConfig(method="lbfgs", history=30, gtol=1e-9, coarse_size=prob.n))
    assert a.iterations == b.iterations
    np.testing.assert_array_equal(a.position, b.position)


def test_coarse_space_on_two_components_reaches_the_plain_optimum(lattice):
    """Clusters may straddle connected components (METIS sees one graph); each component keeps its own
    gauge anchor, and the two-level refiner reaches the same optimum as 4 L^-1 alone."""
    from decentral.ensemble.problem import EnsembleProblem

    a, xa, Ra = lattice(3, (6, 4, 3), noise=0.2, seed=7)
    b, xb, Rb = lattice(3, (5, 5, 3), noise=0.2, seed=8)
    prob = EnsembleProblem.create(3, a.n + b.n, a.radius, np.concatenate([a.i, b.i + a.n]),
                                  np.concatenate([a.j, b.j + a.n]), np.concatenate([a.z, b.z]))
    x, R = np.concatenate([xa, xb + 10.0]), np.concatenate([Ra, Rb])
    base = RefineConfig(method="lbfgs", history=30, gtol=1e-9, max_iter=1000)
    plain = refine(prob, x, R, base)
    two_level = refine(prob, x, R, RefineConfig(**{**base.__dict__, "coarse_size": 25}))
    assert plain.status == two_level.status == "converged"
    assert np.isclose(two_level.cost, plain.cost, rtol=1e-9)
