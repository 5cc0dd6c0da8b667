"""Tests of the closed-form rigid alignment from aggregable statistics (Funiak et al. 2008 eq. 5)."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import minimize_scalar
from scipy.spatial.transform import Rotation

from decentral.ensemble.alignment import AlignmentStats, align_points, merge_point_pairs
from decentral.ensemble.rotation import angle_to_matrix, so3_exp


def _explicit_2d(p, q):
    """Explicit point-set alignment in 2D: minimize the summed squared error over the angle."""
    pc, qc = p - p.mean(0), q - q.mean(0)

    def cost(th):
        return np.sum((pc - qc @ angle_to_matrix(th).T) ** 2)

    grid = np.linspace(-np.pi, np.pi, 721)
    th0 = grid[np.argmin([cost(t) for t in grid])]
    th = minimize_scalar(cost, bounds=(th0 - 0.01, th0 + 0.01), method="bounded", options={"xatol": 1e-12}).x
    R = angle_to_matrix(th)
    return R, p.mean(0) - R @ q.mean(0)


@settings(max_examples=50, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(3, 30))
def test_statistics_solution_equals_explicit_alignment_3d(seed, m):
    """The transform from summed statistics equals scipy's explicit alignment of the centred point sets."""
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(m, 3))
    p = q @ so3_exp(rng.normal(size=(1, 3)))[0].T + rng.normal(size=3) + 0.1 * rng.normal(size=(m, 3))
    T = AlignmentStats.from_points(p, q).solve()
    rot, _ = Rotation.align_vectors(p - p.mean(0), q - q.mean(0))
    np.testing.assert_allclose(T.R, rot.as_matrix(), atol=1e-8)
    np.testing.assert_allclose(T.t, p.mean(0) - rot.as_matrix() @ q.mean(0), atol=1e-8)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(2, 20))
def test_statistics_solution_equals_explicit_alignment_2d(seed, m):
    """In 2D the closed form equals a direct numerical minimization of eq. (5) over the angle."""
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(m, 2))
    p = q @ angle_to_matrix(rng.uniform(-np.pi, np.pi)).T + rng.normal(size=2) + 0.2 * rng.normal(size=(m, 2))
    T = align_points(p, q)
    R, t = _explicit_2d(p, q)
    np.testing.assert_allclose(T.R, R, atol=1e-6)
    np.testing.assert_allclose(T.t, t, atol=1e-6)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(1, 5))
def test_aggregated_statistics_equal_statistics_of_union(seed, parts):
    """Summing the statistics of disjoint parts (as modules aggregate them) gives the union's transform."""
    rng = np.random.default_rng(seed)
    p, q = rng.normal(size=(12, 3)), rng.normal(size=(12, 3))
    cuts = np.sort(rng.choice(np.arange(1, 12), size=parts - 1, replace=False)) if parts > 1 else []
    total = AlignmentStats.zero(3)
    for a, b in zip(np.r_[0, cuts].astype(int), np.r_[cuts, 12].astype(int)):
        total = total + AlignmentStats.from_points(p[a:b], q[a:b])
    whole = AlignmentStats.from_points(p, q)
    np.testing.assert_allclose(total.solve().R, whole.solve().R, atol=1e-10)
    np.testing.assert_allclose(total.solve().residual, whole.solve().residual, atol=1e-9)


def test_residual_equals_explicit_sum():
    """The residual computed from the statistics equals the summed squared error of the transform."""
    rng = np.random.default_rng(1)
    p, q = rng.normal(size=(9, 3)), rng.normal(size=(9, 3))
    T = align_points(p, q)
    assert np.isclose(T.residual, np.sum((p - T.apply(q)) ** 2))


def test_wire_round_trip_has_fixed_size():
    """to_array/from_array round-trips, with 11 values in 2D and 18 in 3D whatever the point count."""
    rng = np.random.default_rng(2)
    for d, size in ((2, 11), (3, 18)):
        s = AlignmentStats.from_points(rng.normal(size=(40, d)), rng.normal(size=(40, d)))
        a = s.to_array()
        assert a.size == size
        back = AlignmentStats.from_array(a)
        np.testing.assert_allclose(back.to_array(), a)


def test_merge_pairs_recover_relative_transform(lattice):
    """Observations across a cut, with each side in its own frame, give back the frames' relation."""
    prob, x, R = lattice(2, (6, 6))
    in_a = x[:, 0] < x[:, 0].mean()
    rng = np.random.default_rng(4)
    G = angle_to_matrix(rng.uniform(-3, 3))
    t = rng.normal(size=2)
    xb, Rb = x @ G.T + t, np.einsum("ab,nbc->nac", G, R)  # B side seen in another frame
    e = np.flatnonzero(in_a[prob.i] & ~in_a[prob.j])
    key = {(a, b): k for k, (a, b) in enumerate(zip(prob.i, prob.j))}
    rev = np.array([key[(b, a)] for a, b in zip(prob.i[e], prob.j[e])])
    a, b = prob.i[e], prob.j[e]
    p, q = merge_point_pairs(x[a], R[a], xb[b], Rb[b], prob.z[e], prob.z[rev])
    T = align_points(p, q)
    np.testing.assert_allclose(T.R, G.T, atol=1e-10)
    np.testing.assert_allclose(T.apply(xb[~in_a]), x[~in_a], atol=1e-10)
