"""The relaxation: both solvers meet at the optimum, the certificate, rounding and gauge."""

import numpy as np
import pytest

from decentral.geometry import rot2, wrap_angle
from decentral.relaxation import (
    SdpSolver,
    certificate,
    reduce_rotations,
    round_gram,
    solve_literal_primal,
    solve_low_rank,
    yaw_hessian,
)


def sync_problem(m: int, noise: float, rng: np.random.Generator, degree: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """A planar rotation synchronization cost Q (2m, 2m) on a ring with chords, and the true angles."""
    truth = rng.uniform(-np.pi, np.pi, m)
    Q = np.zeros((2 * m, 2 * m))
    edges = [(i, (i + s) % m) for i in range(m) for s in range(1, degree // 2 + 1)]
    for i, j in edges:
        Rij = rot2(truth[j] - truth[i] + rng.normal(0, noise))
        # ||R_j - R_i Rij||_F^2
        si, sj = slice(2 * i, 2 * i + 2), slice(2 * j, 2 * j + 2)
        Q[si, si] += np.eye(2)
        Q[sj, sj] += np.eye(2)
        Q[sj, si] -= Rij.T
        Q[si, sj] -= Rij
    return Q, truth


def aligned_error(theta: np.ndarray, truth: np.ndarray) -> float:
    d = wrap_angle(theta - truth)
    return float(np.abs(wrap_angle(d - d[0])).max())


def test_low_rank_recovers_noiseless_rotations():
    """Noiseless synchronization is solved exactly (up to the global gauge) and certified."""
    Q, truth = sync_problem(12, 0.0, np.random.default_rng(0))
    res = solve_low_rank(Q)
    assert res.certified and res.solver == "low-rank"
    assert aligned_error(res.theta, truth) < 1e-8


@pytest.mark.parametrize("seed", range(4))
def test_low_rank_and_sdp_reach_the_same_optimum(seed):
    """At low noise the certified low-rank solution and Clarabel's SDP agree in cost and rotations."""
    Q, _ = sync_problem(10, 0.1, np.random.default_rng(seed))
    fast = solve_low_rank(Q, fallback=False)
    ref = SdpSolver.shared(10).solve(Q)
    assert fast.certified
    assert abs(fast.cost - ref.cost) <= 1e-5 * max(1.0, abs(ref.cost))
    assert aligned_error(fast.theta, ref.theta) < 1e-3


def test_literal_primal_matches_the_dual_form():
    """The paper's P3 as written (3m x 3m, 15b-15c) gives the same rotations as the dual SDP."""
    Q, _ = sync_problem(6, 0.05, np.random.default_rng(7))
    literal = solve_literal_primal(Q)
    fast = solve_low_rank(Q)
    assert abs(literal.cost - fast.cost) <= 1e-5 * max(1.0, abs(fast.cost))
    assert aligned_error(literal.theta, fast.theta) < 1e-3


def test_certificate_rejects_a_suboptimal_critical_point():
    """The certificate matrix has a clearly negative eigenvalue away from the optimum."""
    Q, truth = sync_problem(10, 0.0, np.random.default_rng(3))
    wrong = truth.copy()
    wrong[5:] += np.pi  # a flipped half: far from optimal
    assert certificate(Q, wrong) < -1e-3
    assert certificate(Q, truth) > -1e-9


def test_round_gram_undoes_a_global_reflection():
    """Rounding a Gram matrix picks the factor whose blocks are rotations, not reflections."""
    theta = np.random.default_rng(1).uniform(-3, 3, 7)
    Y = rot2(theta).transpose(1, 0, 2).reshape(2, 14)
    Z = Y.T @ Y
    assert aligned_error(round_gram(Z), theta) < 1e-9


def test_yaw_hessian_has_the_gauge_in_its_null_space():
    """Rotating every yaw together does not change the cost: H @ 1 = 0."""
    Q, truth = sync_problem(8, 0.2, np.random.default_rng(2))
    H = yaw_hessian(Q, solve_low_rank(Q).theta)
    assert np.allclose(H @ np.ones(8), 0.0, atol=1e-9)


def test_reduce_rotations_matches_explicit_minimization():
    """The Schur complement equals minimizing the full quadratic over positions."""
    rng = np.random.default_rng(4)
    m = 5
    C = rng.normal(size=(20, 3 * m))
    C[:, :m] -= C[:, :m].mean(axis=1, keepdims=True)  # position coefficients sum to zero (gauge)
    M = C.T @ C
    Q = reduce_rotations(M, m)
    Y = rng.normal(size=(2, 2 * m))
    P = -Y @ M[:m, m:].T @ np.linalg.pinv(M[:m, :m])
    X = np.hstack([P, Y])
    assert np.isclose(np.trace(X @ M @ X.T), np.trace(Y @ Q @ Y.T))


def test_literal_o2_relaxation_is_loose_where_so2_is_tight():
    """On line-shaped assemblies moving along their axis, Liu et al.'s literal P3 (O(2)) is not tight
    at the optimum, while the SO(2) relaxation certifies it (why we add the commuting-block constraint)."""
    from decentral.factors import NoiseModel, measure_log
    from decentral.relaxation import certificate_o2
    from decentral.window import build_window
    from tests.decentral.test_estimator import noisy_log, scene

    world, configs = scene(6)
    measurements = measure_log(noisy_log(world, configs), NoiseModel())
    problem = build_window(measurements, range(2, 5), "A0")
    Q = reduce_rotations(problem.M, problem.m)
    res = solve_low_rank(Q, fallback=False)
    assert res.certified
    assert certificate_o2(Q, res.theta) < -1e-3
