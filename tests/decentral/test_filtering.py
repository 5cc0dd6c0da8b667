"""EKF pieces for one-node robots: pose algebra, Jacobians, consistency (NEES) and fusion."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from decentral.filtering import (
    compose,
    compose_jacobians,
    covariance_intersection,
    invert,
    nees,
    predict_pose,
    predict_relative,
    project_target,
    update_detection,
    yaw_from_mutual,
)
from decentral.geometry import wrap_angle

poses = st.tuples(
    st.floats(-5, 5), st.floats(-5, 5), st.floats(-np.pi, np.pi)
).map(np.array)

# a forward-looking camera 5 cm ahead and 4 cm above the root, OpenCV axes (x right, y down, z forward)
CAM_R = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
CAM_P = np.array([0.05, 0.0, 0.04])
K = np.array([[400.0, 0.0, 320.0], [0.0, 400.0, 240.0], [0.0, 0.0, 1.0]])
R0 = 0.06


def numeric_jacobian(f, x, eps=1e-6):
    x = np.asarray(x, dtype=float)
    cols = []
    for i in range(len(x)):
        d = np.zeros_like(x)
        d[i] = eps
        diff = f(x + d) - f(x - d)
        if diff.shape[0] == 3:
            diff[2] = wrap_angle(diff[2])
        cols.append(diff / (2 * eps))
    return np.column_stack(cols)


@settings(max_examples=50, deadline=None)
@given(poses, poses)
def test_inverse_undoes_composition(a, b):
    """(a ⊕ b) ⊕ ⊖b == a."""
    back = compose(compose(a, b), invert(b))
    assert np.allclose(back[:2], a[:2], atol=1e-9) and abs(wrap_angle(back[2] - a[2])) < 1e-9


@settings(max_examples=30, deadline=None)
@given(poses, poses)
def test_compose_jacobians_match_finite_differences(a, b):
    """Analytic Jacobians of a ⊕ b agree with central differences."""
    Ja, Jb = compose_jacobians(a, b)
    assert np.allclose(Ja, numeric_jacobian(lambda x: compose(x, b), a), atol=1e-5)
    assert np.allclose(Jb, numeric_jacobian(lambda x: compose(a, x), b), atol=1e-5)


def test_projection_jacobian_matches_finite_differences():
    """d(u, v, r)/d(x, y) of the pinhole model agrees with central differences."""
    pos = np.array([1.3, 0.4])
    _, H, _ = project_target(pos, K, CAM_R, CAM_P, R0)
    num = numeric_jacobian(lambda p: project_target(p, K, CAM_R, CAM_P, R0)[0], pos)
    assert np.allclose(H, num, rtol=1e-5, atol=1e-6)


def test_projection_is_seed000_eq1_inverse():
    """A node straight ahead at distance d projects to the principal point's column with r = f r0 / depth."""
    uvr, _, depth = project_target(np.array([2.05, 0.0]), K, CAM_R, CAM_P, R0)
    assert np.isclose(depth, 2.0) and np.isclose(uvr[0], 320.0) and np.isclose(uvr[2], 400 * R0 / 2.0)


def test_predict_relative_matches_truth_without_noise():
    """Moving the observer by u maps the target's relative pose exactly to ⊖u ⊕ s."""
    s = np.array([2.0, 1.0, 0.3])
    u = np.array([0.1, 0.02, 0.05])
    m, _ = predict_relative(s, np.eye(3) * 1e-4, u, np.zeros((3, 3)))
    world_target = s  # observer at the origin at k-1
    assert np.allclose(m, compose(invert(u), world_target))


def test_predict_relative_with_target_motion_matches_truth():
    """With both robots' motions known, the track follows ⊖u ⊕ s ⊕ w exactly."""
    s, u, w = np.array([2.0, 1.0, 0.3]), np.array([0.1, 0.02, 0.05]), np.array([0.05, -0.01, -0.2])
    m, _ = predict_relative(s, np.eye(3) * 1e-4, u, np.zeros((3, 3)), w, np.zeros((3, 3)))
    assert np.allclose(m, compose(compose(invert(u), s), w))


def test_predict_relative_jacobians_match_finite_differences():
    """The propagated covariance equals J P J^T with J from central differences over (s, u, w)."""
    s, u, w = np.array([2.0, 1.0, 0.3]), np.array([0.1, 0.02, 0.05]), np.array([0.05, -0.01, -0.2])
    P, U, W = np.diag([0.01, 0.02, 0.03]), np.diag([1e-3, 2e-3, 3e-3]), np.diag([4e-3, 5e-3, 6e-3])
    _, got = predict_relative(s, P, u, U, w, W)
    f = lambda x: compose(compose(invert(x[3:6]), x[:3]), x[6:])
    J = numeric_jacobian(f, np.concatenate([s, u, w]))
    big = np.zeros((9, 9))
    big[:3, :3], big[3:6, 3:6], big[6:, 6:] = P, U, W
    assert np.allclose(got, J @ big @ J.T, atol=1e-8)


def _chi2_band(dof: int, runs: int, alpha: float = 0.001):
    lo = stats.chi2.ppf(alpha / 2, dof * runs) / runs
    hi = stats.chi2.ppf(1 - alpha / 2, dof * runs) / runs
    return lo, hi


def test_own_motion_ekf_is_consistent():
    """Dead-reckoned pose NEES averaged over 200 Monte Carlo runs lies in the 99.9 % chi-square band."""
    rng = np.random.default_rng(0)
    runs, steps = 100, 40
    U = np.diag([0.01**2, 0.005**2, 0.01**2])
    errs = np.zeros((runs, steps))
    for r in range(runs):
        truth, mean, cov = np.zeros(3), np.zeros(3), np.zeros((3, 3))
        for k in range(steps):
            u_true = np.array([0.05, 0.0, 0.08 * np.sin(0.2 * k)])
            truth = compose(truth, u_true)
            u_meas = u_true + rng.multivariate_normal(np.zeros(3), U)
            mean, cov = predict_pose(mean, cov, u_meas, U)
            errs[r, k] = nees(truth - mean, cov)
    lo, hi = _chi2_band(3, runs)
    avg = errs.mean(axis=0)
    assert np.all((avg[5:] > lo) & (avg[5:] < hi)), (avg.min(), avg.max(), lo, hi)


def _track_run(rng, steps=60, mutual_every=3):
    """A moving observer tracks a random-walking target with its camera and mutual detections."""
    U = np.diag([0.004**2, 0.004**2, 0.006**2])
    Q = np.diag([0.01**2, 0.01**2, 0.01**2])
    Rz = np.diag([1.0, 1.0, 0.5**2])
    obs_w = np.zeros(3)
    tgt_w = np.array([2.0, 0.3, 2.5])
    s_true = compose(invert(obs_w), tgt_w)
    t_obs = s_true[:2]
    b = invert(s_true)[:2]
    mean = np.array([*t_obs, yaw_from_mutual(t_obs, b)]) + rng.normal(0, [0.05, 0.05, 0.05])
    cov = np.diag([0.05**2, 0.05**2, 0.05**2])
    out = []
    for k in range(steps):
        u = np.array([0.01, 0.0, 0.01 * np.cos(0.1 * k)])  # target stays 1.2-2 m ahead
        obs_w = compose(obs_w, u)
        tgt_w = compose(tgt_w, rng.multivariate_normal(np.zeros(3), Q))
        s_true = compose(invert(obs_w), tgt_w)
        mean, cov = predict_relative(mean, cov, u + rng.multivariate_normal(np.zeros(3), U), U, target_motion_cov=Q)
        uvr, _, _ = project_target(s_true[:2], K, CAM_R, CAM_P, R0)
        z = uvr + rng.multivariate_normal(np.zeros(3), Rz)
        res = update_detection(mean, cov, z, Rz, K, CAM_R, CAM_P, R0)
        mean, cov = res.mean, res.cov
        if k % mutual_every == 0:
            uvr2, _, _ = project_target(invert(s_true)[:2], K, CAM_R, CAM_P, R0)
            z2 = uvr2 + rng.multivariate_normal(np.zeros(3), Rz)
            res = update_detection(mean, cov, z2, Rz, K, CAM_R, CAM_P, R0, mutual=True)
            mean, cov = res.mean, res.cov
        e = s_true - mean
        out.append(nees(e, cov))
    return np.array(out)


def test_relative_track_ekf_is_consistent():
    """Track NEES (camera + mutual detections, moving target) averaged over 60 runs is in the chi-square band."""
    rng = np.random.default_rng(1)
    runs = 60
    errs = np.stack([_track_run(rng, steps=40) for _ in range(runs)])
    lo, hi = _chi2_band(3, runs)
    avg = errs.mean(axis=0)
    # after the first few steps (initial linearization) the filter must be consistent
    assert np.mean((avg[3:] > lo) & (avg[3:] < hi)) >= 0.95, (avg.min(), avg.max(), lo, hi)


def test_own_detection_alone_does_not_inform_yaw():
    """An update from the observer's own camera leaves the yaw variance unchanged (a sphere has no heading)."""
    mean, cov = np.array([2.0, 0.2, 0.0]), np.diag([0.1, 0.1, 2.0])
    uvr, _, _ = project_target(mean[:2], K, CAM_R, CAM_P, R0)
    res = update_detection(mean, cov, uvr + 1.0, np.eye(3), K, CAM_R, CAM_P, R0)
    assert res.accepted and np.isclose(res.cov[2, 2], 2.0) and res.cov[0, 0] < 0.1


def test_mutual_detection_informs_yaw():
    """A detection made by the target's camera shrinks the yaw variance."""
    mean, cov = np.array([2.0, 0.2, 2.9]), np.diag([0.01, 0.01, 0.2])
    s = np.array([2.0, 0.2, 3.0])
    uvr, _, _ = project_target(invert(s)[:2], K, CAM_R, CAM_P, R0)
    res = update_detection(mean, cov, uvr, np.eye(3), K, CAM_R, CAM_P, R0, mutual=True)
    assert res.accepted and res.cov[2, 2] < 0.05 and abs(res.mean[2] - 3.0) < abs(2.9 - 3.0)


def test_gate_rejects_outliers():
    """A measurement far outside the predicted circle is refused and the prior kept."""
    mean, cov = np.array([2.0, 0.0, 0.0]), np.diag([0.01, 0.01, 0.1])
    uvr, _, _ = project_target(mean[:2], K, CAM_R, CAM_P, R0)
    res = update_detection(mean, cov, uvr + 200.0, np.eye(3), K, CAM_R, CAM_P, R0, gate=stats.chi2.ppf(0.999, 3))
    assert not res.accepted and np.array_equal(res.mean, mean)


def test_target_behind_camera_is_not_used():
    """A measurement of a target predicted behind the camera is refused."""
    res = update_detection(np.array([-2.0, 0.0, 0.0]), np.eye(3) * 0.01, np.array([320.0, 240.0, 12.0]),
                           np.eye(3), K, CAM_R, CAM_P, R0)
    assert not res.accepted


@settings(max_examples=30, deadline=None)
@given(poses)
def test_yaw_from_mutual_recovers_relative_yaw(s):
    """The closed-form yaw from both robots' views equals the true relative yaw."""
    if np.hypot(s[0], s[1]) < 0.1:
        return
    got = yaw_from_mutual(s[:2], invert(s)[:2])
    assert abs(wrap_angle(got - s[2])) < 1e-9


def test_covariance_intersection_is_conservative():
    """CI of two estimates has a covariance no smaller than the exact fusion of independent ones."""
    a, A = np.array([1.0, 0.0, 0.1]), np.diag([0.04, 0.01, 0.02])
    b, B = np.array([1.1, 0.05, 0.12]), np.diag([0.01, 0.04, 0.02])
    c, C, w = covariance_intersection(a, A, b, B)
    exact = np.linalg.inv(np.linalg.inv(A) + np.linalg.inv(B))
    assert 0 <= w <= 1
    assert np.all(np.linalg.eigvalsh(C - exact) >= -1e-12)
    assert np.linalg.det(C) <= min(np.linalg.det(A), np.linalg.det(B)) + 1e-15


def test_covariance_intersection_wraps_yaw():
    """Fusing yaws on both sides of ±pi gives a yaw near pi, not near 0."""
    c, _, _ = covariance_intersection(np.array([0, 0, np.pi - 0.05]), np.eye(3) * 0.01,
                                      np.array([0, 0, -np.pi + 0.05]), np.eye(3) * 0.01)
    assert abs(wrap_angle(c[2] - np.pi)) < 0.06
