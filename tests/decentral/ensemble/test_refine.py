"""Tests of maximum-likelihood refinement (Funiak et al. 2008 eq. 3)."""

import numpy as np
import pytest

from decentral.ensemble.model import negative_log_likelihood
from decentral.ensemble.refine import LaplacianSolver, RefineConfig, refine
from decentral.ensemble.rotation import angle_to_matrix, matrix_to_angle, matrix_to_quat, so3_exp


def _perturb(x, R, rng, dim, s=0.2):
    dR = angle_to_matrix(s * rng.normal(size=len(x))) if dim == 2 else so3_exp(s * rng.normal(size=(len(x), 3)))
    return x + 0.3 * 0.05 * rng.normal(size=x.shape), R @ dR


@pytest.mark.parametrize("dim,shape", [(2, (8, 7)), (3, (4, 4, 3))])
@pytest.mark.parametrize("method", ["alternating", "lbfgs", "lm", "pcg"])
def test_noiseless_refinement_reaches_zero_cost(lattice, dim, shape, method):
    """From a perturbed truth on a noiseless lattice, refinement drives the likelihood cost to ~0."""
    prob, x, R = lattice(dim, shape)
    x0, R0 = _perturb(x, R, np.random.default_rng(0), dim)
    res = refine(prob, x0, R0, RefineConfig(method=method, gtol=1e-10, max_iter=3000))
    assert res.status == "converged"
    assert res.cost < 1e-16


def test_methods_agree_on_noisy_optimum(lattice):
    """Alternating sweeps and Levenberg-Marquardt reach the same maximum likelihood."""
    prob, x, R = lattice(2, (9, 9), noise=0.2, seed=3)
    a = refine(prob, x, R, RefineConfig(method="alternating", gtol=1e-9))
    b = refine(prob, x, R, RefineConfig(method="lm", gtol=1e-9))
    assert np.isclose(a.cost, b.cost, rtol=1e-7)


def test_refinement_never_increases_cost(lattice):
    """The returned cost is at most the starting cost, whatever the iteration budget."""
    prob, x, R = lattice(3, (4, 3, 3), noise=0.3, seed=5)
    x0, R0 = _perturb(x, R, np.random.default_rng(1), 3, s=0.5)
    start = negative_log_likelihood(prob, x0, matrix_to_quat(R0))
    for it in (1, 2, 5):
        res = refine(prob, x0, R0, RefineConfig(max_iter=it))
        assert res.cost <= start + 1e-15
        assert np.isclose(res.cost, negative_log_likelihood(prob, res.position, matrix_to_quat(res.rotation)))


def test_reported_cost_matches_model(lattice):
    """The cost in the result is the model's negative log-likelihood at the returned poses."""
    prob, x, R = lattice(2, (6, 6), noise=0.1)
    res = refine(prob, x, R)
    assert np.isclose(res.cost, negative_log_likelihood(prob, res.position, matrix_to_angle(res.rotation)))


@pytest.mark.parametrize("dim,shape", [(2, (9, 9)), (3, (4, 4, 3))])
def test_pcg_reaches_the_alternating_optimum(lattice, dim, shape):
    """The paper's refiner (preconditioned nonlinear CG) reaches the same noisy maximum likelihood."""
    prob, x, R = lattice(dim, shape, noise=0.2, seed=3)
    a = refine(prob, x, R, RefineConfig(method="alternating", gtol=1e-9, max_iter=2000))
    b = refine(prob, x, R, RefineConfig(method="pcg", gtol=1e-9, max_iter=5000))
    assert np.isclose(a.cost, b.cost, rtol=1e-7)


def test_pcg_never_increases_cost_and_counts_iterations(lattice):
    """Each PCG iteration is accepted only if it lowers the cost; the budget caps the count."""
    prob, x, R = lattice(3, (4, 3, 3), noise=0.3, seed=5)
    x0, R0 = _perturb(x, R, np.random.default_rng(1), 3, s=0.5)
    start = negative_log_likelihood(prob, x0, matrix_to_quat(R0))
    costs = [refine(prob, x0, R0, RefineConfig(method="pcg", max_iter=k, gtol=0.0, ftol=0.0)) for k in (1, 3, 10)]
    assert [c.iterations for c in costs] == [1, 3, 10]
    assert costs[0].cost < start and costs[1].cost <= costs[0].cost and costs[2].cost <= costs[1].cost
    assert np.isclose(costs[2].cost, negative_log_likelihood(prob, costs[2].position, matrix_to_quat(costs[2].rotation)))


def test_l2_gradient_norm_is_at_least_the_largest_entry(lattice):
    """With gnorm="l2" the reported gradient norm bounds the largest entry (same stopping point or later)."""
    prob, x, R = lattice(2, (6, 6), noise=0.2, seed=2)
    x0, R0 = _perturb(x, R, np.random.default_rng(0), 2)
    a = refine(prob, x0, R0, RefineConfig(method="pcg", max_iter=5, gtol=0.0, ftol=0.0))
    b = refine(prob, x0, R0, RefineConfig(method="pcg", max_iter=5, gtol=0.0, ftol=0.0, gnorm="l2"))
    assert np.allclose(a.position, b.position)
    assert b.gradient_norm >= a.gradient_norm


@pytest.mark.parametrize("method", ["alternating", "lbfgs", "lm", "pcg"])
def test_l2_tolerance_is_honoured_by_every_method(lattice, method):
    """With gnorm="l2" each method stops converged with a Euclidean gradient norm below gtol."""
    prob, x, R = lattice(2, (6, 6), noise=0.2, seed=4)
    x0, R0 = _perturb(x, R, np.random.default_rng(2), 2)
    res = refine(prob, x0, R0, RefineConfig(method=method, gtol=1e-3, gnorm="l2", ftol=0.0, max_iter=3000))
    assert res.status == "converged" and res.gradient_norm <= 1e-3


def test_unknown_gradient_norm_is_refused(lattice):
    """A misspelt gnorm raises instead of silently using another norm."""
    prob, x, R = lattice(2, (3, 3))
    with pytest.raises(ValueError):
        refine(prob, x, R, RefineConfig(gnorm="L2"))


@pytest.mark.parametrize("dim,shape", [(2, (9, 9)), (3, (4, 4, 3))])
def test_lbfgs_reaches_the_alternating_optimum(lattice, dim, shape):
    """L-BFGS on the centres (orientations fitted in closed form) reaches the alternating sweeps' optimum."""
    prob, x, R = lattice(dim, shape, noise=0.2, seed=3)
    x0, R0 = _perturb(x, R, np.random.default_rng(4), dim)
    a = refine(prob, x0, R0, RefineConfig(method="alternating", gtol=1e-9, max_iter=2000))
    b = refine(prob, x0, R0, RefineConfig(method="lbfgs", gtol=1e-9, max_iter=2000))
    assert b.status == "converged"
    assert np.isclose(a.cost, b.cost, rtol=1e-9)


def test_lbfgs_never_increases_cost(lattice):
    """Every accepted L-BFGS step lowers the cost (Armijo), whatever the iteration budget."""
    prob, x, R = lattice(3, (4, 3, 3), noise=0.3, seed=5)
    x0, R0 = _perturb(x, R, np.random.default_rng(1), 3, s=0.5)
    costs = [refine(prob, x0, R0, RefineConfig(method="lbfgs", max_iter=k, gtol=0.0, ftol=0.0)).cost for k in (0, 1, 3, 10)]
    assert all(b <= a for a, b in zip(costs, costs[1:]))
    assert costs[-1] < costs[0]


def _held_ring(prob, centre, hops):
    """Modules within ``hops`` of module ``centre`` (free) and everything else (held)."""
    adj = prob.adjacency()
    free = np.zeros(prob.n, dtype=bool)
    free[centre] = True
    for _ in range(hops):
        free |= (adj @ free.astype(float)) > 0
    return ~free


@pytest.mark.parametrize("method", ["alternating", "lbfgs"])
@pytest.mark.parametrize("dim,shape,centre", [(2, (10, 9), 44), (3, (5, 5, 4), 62)])
def test_held_modules_recover_the_optimum_around_them(lattice, method, dim, shape, centre):
    """With the held modules at the full optimum, refining the others from a perturbed start
    returns to that optimum, and the held modules do not move."""
    prob, x, R = lattice(dim, shape, noise=0.2, seed=6)
    opt = refine(prob, x, R, RefineConfig(method="lbfgs", gtol=1e-10, max_iter=3000))
    held = _held_ring(prob, centre, 2)
    x0, R0 = opt.position.copy(), opt.rotation.copy()
    xp, Rp = _perturb(opt.position, opt.rotation, np.random.default_rng(2), dim)
    x0[~held], R0[~held] = xp[~held], Rp[~held]
    res = refine(prob, x0, R0, RefineConfig(method=method, gtol=1e-10, max_iter=3000), fixed=held)
    assert res.status == "converged"
    # held modules move by no more than the rounding of the unit and angle conversions
    np.testing.assert_allclose(res.position[held], opt.position[held], rtol=0, atol=1e-14)
    np.testing.assert_allclose(res.rotation[held], opt.rotation[held], rtol=0, atol=1e-14)
    np.testing.assert_allclose(res.position, opt.position, atol=1e-5 * prob.radius)
    assert np.isclose(res.cost, opt.cost, rtol=1e-9)


def test_held_modules_need_a_refiner_that_supports_them(lattice):
    """Holding modules with the LM or PCG refiner raises instead of silently moving them."""
    prob, x, R = lattice(2, (3, 3))
    held = np.zeros(prob.n, dtype=bool)
    held[0] = True
    for method in ("lm", "pcg"):
        with pytest.raises(ValueError):
            refine(prob, x, R, RefineConfig(method=method), fixed=held)


def test_laplacian_solver_holds_the_given_centres(lattice):
    """With held modules, the solve keeps them at the given centres and satisfies the normal equations
    (L c = B^T t) on every other module."""
    prob, x, R = lattice(2, (6, 5), noise=0.2, seed=1)
    rng = np.random.default_rng(3)
    held = np.zeros(prob.n, dtype=bool)
    held[[0, 7, 29]] = True
    t = rng.normal(size=(prob.num_observations, 2))
    current = rng.normal(size=(prob.n, 2))
    c = LaplacianSolver(prob.n, prob.i, prob.j, fixed=held).solve(t, current)
    np.testing.assert_array_equal(c[held], current[held])
    # gradient of sum_e |c_j - c_i - t_e|^2 vanishes at every free module
    r = c[prob.j] - c[prob.i] - t
    g = np.zeros_like(c)
    np.add.at(g, prob.j, r)
    np.add.at(g, prob.i, -r)
    np.testing.assert_allclose(g[~held], 0.0, atol=1e-9)


@pytest.mark.parametrize("dim,shape", [(2, (9, 8)), (3, (5, 4, 4))])
def test_nested_dissection_solve_equals_minimum_degree_solve(lattice, dim, shape):
    """The Laplacian solve gives the same centres (to rounding) whichever fill-reducing ordering
    factorizes it, with and without held modules."""
    prob, x, R = lattice(dim, shape, noise=0.2, seed=2)
    rng = np.random.default_rng(4)
    t = rng.normal(size=(prob.num_observations, dim))
    current = rng.normal(size=(prob.n, dim))
    held = np.zeros(prob.n, dtype=bool)
    held[[1, 17]] = True
    for fixed in (None, held):
        nd = LaplacianSolver(prob.n, prob.i, prob.j, fixed=fixed, ordering="nd")
        mmd = LaplacianSolver(prob.n, prob.i, prob.j, fixed=fixed, ordering="mmd")
        assert nd.perm is not None and mmd.perm is None
        np.testing.assert_allclose(nd.solve(t, current), mmd.solve(t, current), atol=1e-10)


def test_nested_dissection_is_a_reproducible_permutation(lattice):
    """The METIS ordering is a permutation of the free modules and the same on every call."""
    from decentral.ensemble.ordering import nested_dissection

    prob, _, _ = lattice(3, (6, 5, 4))
    first = LaplacianSolver(prob.n, prob.i, prob.j, ordering="nd").perm
    np.testing.assert_array_equal(np.sort(first), np.arange(prob.n - 1))
    np.testing.assert_array_equal(first, LaplacianSolver(prob.n, prob.i, prob.j, ordering="nd").perm)
    lap = prob.adjacency()
    np.testing.assert_array_equal(np.sort(nested_dissection(lap)), np.arange(prob.n))


def test_lbfgs_refinement_does_not_depend_on_the_ordering(lattice):
    """L-BFGS reaches the same optimum in the same number of iterations with either ordering."""
    prob, x, R = lattice(3, (5, 5, 4), noise=0.2, seed=5)
    x0, R0 = _perturb(x, R, np.random.default_rng(6), 3)
    a = refine(prob, x0, R0, RefineConfig(method="lbfgs", ordering="nd", max_iter=60, history=30))
    b = refine(prob, x0, R0, RefineConfig(method="lbfgs", ordering="mmd", max_iter=60, history=30))
    assert a.iterations == b.iterations
    np.testing.assert_allclose(a.position, b.position, atol=1e-9)
    assert abs(a.cost - b.cost) <= 1e-9 * max(b.cost, 1e-12)


def test_unknown_ordering_is_rejected(lattice):
    """An unknown ordering name raises ValueError instead of silently falling back."""
    prob, x, R = lattice(2, (3, 3))
    with pytest.raises(ValueError):
        LaplacianSolver(prob.n, prob.i, prob.j, ordering="metis")
    with pytest.raises(ValueError):
        refine(prob, x, R, RefineConfig(method="lbfgs", ordering="metis"))


def test_auto_ordering_dissects_only_large_3d_laplacians():
    """"auto" picks nested dissection for 3D ensembles from ND_MIN_SIZE modules and minimum degree
    for planar ones and small 3D ones; an explicit choice is kept."""
    from decentral.ensemble.ordering import ND_MIN_SIZE, choose_ordering

    assert choose_ordering("auto", 3, ND_MIN_SIZE) == "nd"
    assert choose_ordering("auto", 3, ND_MIN_SIZE - 1) == "mmd"
    assert choose_ordering("auto", 2, 100 * ND_MIN_SIZE) == "mmd"
    assert choose_ordering("nd", 2, 10) == "nd"
    assert choose_ordering("mmd", 3, 100 * ND_MIN_SIZE) == "mmd"


def test_decrease_test_looks_back_over_its_window():
    """With a window of one a single small step stops the run; with a longer window it stops only
    when the steps of the whole window together lowered the cost by less than ftol."""
    from decentral.ensemble.refiners.base import DecreaseTest

    costs = [1.0, 0.5, 0.5 - 1e-14, 0.25, 0.25 - 1e-14, 0.25 - 2e-14, 0.25 - 3e-14]
    one = DecreaseTest(RefineConfig(ftol=1e-12, ftol_window=1), costs[0])
    assert [one(c) for c in costs[1:]] == [False, True, False, True, True, True]
    three = DecreaseTest(RefineConfig(ftol=1e-12, ftol_window=3), costs[0])
    assert [three(c) for c in costs[1:]] == [False, False, False, False, False, True]
