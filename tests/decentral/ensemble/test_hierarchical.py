"""Tests of Funiak et al.'s Algorithm 1 (normalized-cut localization)."""

import numpy as np
import pytest

from decentral.ensemble.hierarchical import HierarchyConfig, normcut_localize
from decentral.ensemble.metrics import aligned
from decentral.ensemble.problem import EnsembleProblem
from decentral.ensemble.refine import RefineConfig, refine

SMALL = HierarchyConfig(leaf_size=16, abstract_size=8)
#: "exact", in module radii (and for rotation entries): the top refinement stops at a largest gradient entry
#: of 1e-6 (ftol 1e-10), so a noiseless estimate is exact to about 1e-6, the last digit depending on the
#: BLAS kernels of the machine (an older x86 path moved one rotation entry by 1.03e-6)
EXACT = 1e-5


def _rms(est, truth, radius):
    return np.sqrt(np.mean(np.sum((aligned(est, truth) - truth) ** 2, axis=1))) / radius


@pytest.mark.parametrize("cut", ["abstract", "exact"])
def test_exact_recovery_on_noiseless_planar_lattice(lattice, cut):
    """Noiseless 2D lattice: every module recovered exactly up to one rigid motion."""
    prob, x, R = lattice(2, (14, 12))
    res = normcut_localize(prob, np.random.default_rng(0), HierarchyConfig(leaf_size=16, abstract_size=8, cut=cut))
    assert _rms(res.estimate.position, x, prob.radius) < EXACT
    assert res.status == "ok"


def test_exact_recovery_on_noiseless_cubic_lattice(lattice):
    """Noiseless 3D lattice: positions and relative orientations recovered exactly."""
    prob, x, R = lattice(3, (6, 5, 5))
    res = normcut_localize(prob, np.random.default_rng(0), SMALL)
    est = res.estimate
    assert _rms(est.position, x, prob.radius) < EXACT
    # relative orientations: R_est_0^T R_est_i equals R_0^T R_i (the global rotation cancels)
    rel_est = np.einsum("ba,nbc->nac", est.rotation[0], est.rotation)
    rel_true = np.einsum("ba,nbc->nac", R[0], R)
    np.testing.assert_allclose(rel_est, rel_true, atol=EXACT)


def test_relabelling_leaves_aligned_estimate_unchanged(lattice):
    """Permuting module ids gives the same estimate after rigid alignment (noisy data)."""
    prob, x, R = lattice(2, (12, 12), noise=0.15, seed=2)
    perm = np.random.default_rng(9).permutation(prob.n)
    inv = np.argsort(perm)  # new id of old module k is inv[k]
    p2 = EnsembleProblem.create(2, prob.n, prob.radius, inv[prob.i], inv[prob.j], prob.z)
    cfg = HierarchyConfig(leaf_size=16, cut="exact", final_refine=RefineConfig(max_iter=500, gtol=1e-9))
    a = normcut_localize(prob, np.random.default_rng(0), cfg).estimate.position
    b = normcut_localize(p2, np.random.default_rng(0), cfg).estimate.position[inv]
    assert _rms(b, a, prob.radius) < 1e-5


def test_result_is_a_likelihood_optimum(lattice):
    """Further refinement from the returned estimate does not lower the cost noticeably."""
    prob, x, R = lattice(2, (10, 10), noise=0.2, seed=4)
    res = normcut_localize(prob, np.random.default_rng(1), SMALL)
    more = refine(prob, res.estimate.position, res.estimate.rotation, RefineConfig(method="lm", gtol=1e-10))
    assert more.cost >= res.cost * (1 - 1e-6)


def test_disconnected_components_do_not_overlap(lattice):
    """Two separate ensembles are each localized and laid side by side without overlap."""
    a, xa, _ = lattice(2, (5, 5), seed=1)
    b, xb, _ = lattice(2, (4, 6), seed=2)
    prob = EnsembleProblem.create(2, a.n + b.n, a.radius, np.r_[a.i, b.i + a.n], np.r_[a.j, b.j + a.n],
                                  np.r_[a.z, b.z])
    est = normcut_localize(prob, np.random.default_rng(0), SMALL).estimate
    assert set(est.component[: a.n]) != set(est.component[a.n:])
    assert _rms(est.position[: a.n], xa, a.radius) < EXACT and _rms(est.position[a.n:], xb, a.radius) < EXACT
    gap = np.linalg.norm(est.position[: a.n, None] - est.position[None, a.n:], axis=2).min()
    assert gap > 2 * a.radius


def test_iterations_are_charged_to_every_module(lattice):
    """Each module is charged at least the iterations of the final refinement it took part in."""
    prob, _, _ = lattice(2, (10, 10), noise=0.1)
    res = normcut_localize(prob, np.random.default_rng(0), SMALL)
    top = res.hierarchy[-1]
    assert top.nodes.size == prob.n
    assert np.all(res.iterations_per_module >= top.refine_iterations)


def test_isolated_module_is_placed_without_nan():
    """A module with no observations still gets a finite pose, in its own component."""
    prob = EnsembleProblem.create(2, 3, 1.0, [0, 1], [1, 0], [[1.0, 0.0], [-1.0, 0.0]])
    est = normcut_localize(prob, np.random.default_rng(0)).estimate
    assert np.all(np.isfinite(est.position)) and np.all(np.isfinite(est.orientation))
    assert est.component[2] != est.component[0]


@pytest.mark.parametrize("dim,shape", [(2, (22, 20)), (3, (8, 8, 7))])
def test_seam_refinement_reaches_the_full_refinement_optimum(lattice, dim, shape):
    """Refining only the seams below the top reaches the optimum that refining every level in full
    reaches (same cost, same aligned positions), for fewer refinement iterations per module."""
    prob, x, R = lattice(dim, shape, noise=0.2, seed=7)
    base = dict(leaf_size=16, abstract_size=8, final_refine=RefineConfig(method="lbfgs", history=30, max_iter=1000,
                                                                          gtol=1e-9))
    full = normcut_localize(prob, np.random.default_rng(0), HierarchyConfig(seam_hops=0, **base))
    seam = normcut_localize(prob, np.random.default_rng(0), HierarchyConfig(seam_hops=2, **base))
    assert full.status == seam.status == "ok"
    assert np.isclose(seam.cost, full.cost, rtol=1e-9)
    assert _rms(seam.estimate.position, full.estimate.position, prob.radius) < 1e-5
    assert seam.iterations_per_module.mean() < full.iterations_per_module.mean()


def test_seam_band_is_the_neighbourhood_of_the_crossing_observations(lattice):
    """The band holds both ends of every crossing observation and every module within the given hops
    of one, nothing else; the ring is exactly the band's outside neighbours."""
    from scipy.sparse.csgraph import shortest_path

    from decentral.ensemble.hierarchical import seam_band

    prob, _, _ = lattice(2, (16, 6))
    x_index = np.arange(prob.n) // 6  # lattice rows of the (16, 6) grid
    part = (x_index >= 8).astype(np.int64)
    band = seam_band(prob, part, 2)
    cross = np.unique(np.r_[prob.i, prob.j][np.r_[part[prob.i] != part[prob.j], part[prob.i] != part[prob.j]]])
    hops = shortest_path(prob.adjacency(), unweighted=True, indices=cross).min(axis=0)
    np.testing.assert_array_equal(band.free, hops <= 2)
    np.testing.assert_array_equal(band.ring, hops == 3)
    assert seam_band(prob, part, 20) is None  # the band would cover everything: refine the whole set


def test_seam_fraction_zero_is_full_level_refinement(lattice):
    """With seam_fraction 0 no merge is small enough for the seam rule: the run equals seam_hops 0."""
    prob, _, _ = lattice(2, (16, 14), noise=0.2, seed=8)
    a = normcut_localize(prob, np.random.default_rng(0), HierarchyConfig(leaf_size=16, abstract_size=8, seam_fraction=0.0))
    b = normcut_localize(prob, np.random.default_rng(0), HierarchyConfig(leaf_size=16, abstract_size=8, seam_hops=0))
    np.testing.assert_array_equal(a.estimate.position, b.estimate.position)
    np.testing.assert_array_equal(a.iterations_per_module, b.iterations_per_module)


def test_hierarchy_order_puts_each_cut_separator_after_its_parts(lattice):
    """The elimination order built from a cut lists every module once, the parts' own orders first and
    the later-part ends of the crossing observations last, so eliminating in that order never couples
    the two parts before the separator."""
    from decentral.ensemble.ordering import hierarchy_order

    prob, _, _ = lattice(2, (12, 6))
    part = (np.arange(prob.n) // 6 >= 6).astype(np.int64)  # left and right halves of the grid
    orders = [np.flatnonzero(part == p)[::-1] for p in (0, 1)]  # any order within each part
    order = hierarchy_order(prob.i, prob.j, part, orders)
    np.testing.assert_array_equal(np.sort(order), np.arange(prob.n))
    crossing = part[prob.i] != part[prob.j]
    separator = np.unique(np.where(part[prob.i] > part[prob.j], prob.i, prob.j)[crossing])
    np.testing.assert_array_equal(np.sort(order[-separator.size:]), separator)
    rest = order[: -separator.size]
    np.testing.assert_array_equal(rest, np.concatenate([o[~np.isin(o, separator)] for o in orders]))


@pytest.mark.parametrize("dim,shape", [(2, (20, 18)), (3, (8, 7, 7))])
def test_hierarchy_elimination_order_leaves_algorithm_1_unchanged(lattice, dim, shape):
    """Factorizing the full-level Laplacians in the hierarchy's order instead of minimum degree changes
    nothing but rounding: same cost, same estimate, about the same iterations (rounding can move a
    stopping test by an iteration)."""
    prob, _, _ = lattice(dim, shape, noise=0.2, seed=9)

    def config(ordering):
        r = RefineConfig(method="lbfgs", history=30, max_iter=100, gtol=1e-3, ordering=ordering)
        return HierarchyConfig(leaf_size=16, abstract_size=8, seam_hops=0, level_refine=r,
                               final_refine=RefineConfig(method="lbfgs", history=30, max_iter=300,
                                                         gtol=1e-6, ordering=ordering))

    auto = normcut_localize(prob, np.random.default_rng(0), config("auto"))
    mmd = normcut_localize(prob, np.random.default_rng(0), config("mmd"))
    assert np.isclose(auto.cost, mmd.cost, rtol=1e-9)
    assert _rms(auto.estimate.position, mmd.estimate.position, prob.radius) < EXACT
    assert abs(auto.iterations_per_module.mean() / mmd.iterations_per_module.mean() - 1) < 0.1


def test_refine_rejects_an_elimination_order_that_is_not_a_permutation(lattice):
    """An elimination order with a repeated or missing module is refused (ValueError), not used."""
    prob, x, R = lattice(2, (4, 4))
    bad = np.arange(prob.n)
    bad[3] = 2
    with pytest.raises(ValueError):
        refine(prob, x, R, RefineConfig(method="lbfgs"), elimination=bad)
