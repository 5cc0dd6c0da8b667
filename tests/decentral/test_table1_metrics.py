"""Properties of the Table I scores in decentral.metrics."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from decentral.errors import InputError
from decentral.metrics import GroundTruth, relative_truth, score_estimate
from decentral.observations import Estimate, EstimateStep, PlanarPose


def _rz(t):
    c, s = np.cos(t), np.sin(t)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def _truth(rng, T=6, names=("A0", "A1", "A2")):
    times = np.arange(T) * 0.2
    R, p = {}, {}
    for i, n in enumerate(names):
        yaw = rng.uniform(-np.pi, np.pi, T)
        R[n] = np.stack([_rz(y) for y in yaw])
        p[n] = np.column_stack([rng.uniform(-3, 3, T) + 4 * i, rng.uniform(-3, 3, T), rng.uniform(0, 1, T)])
    return GroundTruth(times, R, p)


def _perfect(truth, reference="A0", skip=()):
    steps = []
    for k, t in enumerate(truth.times):
        poses = {}
        for n in truth.R:
            if n == reference or (n, k) in skip:
                continue
            p, th = relative_truth(truth, reference, n)
            poses[n] = PlanarPose(p[k], float(th[k]))
        steps.append(EstimateStep(float(t), poses))
    return Estimate(reference, tuple(steps), {})


def _moved(truth, yaw, shift):
    Rw = _rz(yaw)
    return GroundTruth(
        truth.times,
        {n: np.einsum("ij,tjk->tik", Rw, R) for n, R in truth.R.items()},
        {n: p @ Rw.T + shift for n, p in truth.p.items()},
    )


seeds = st.integers(0, 2**32 - 1)


@settings(max_examples=25, deadline=None)
@given(seeds)
def test_perfect_estimate_scores_zero(seed):
    """An estimate equal to the true relative poses has zero errors and full coverage."""
    truth = _truth(np.random.default_rng(seed))
    score = score_estimate(truth, _perfect(truth))
    assert score.overall.position_m == pytest.approx(0, abs=1e-12)
    assert score.overall.relative_position_pct == pytest.approx(0, abs=1e-10)
    assert score.overall.yaw_deg == pytest.approx(0, abs=1e-10)
    assert score.overall.coverage == 1.0


@settings(max_examples=25, deadline=None)
@given(seeds, st.floats(-np.pi, np.pi), st.lists(st.floats(-50, 50), min_size=3, max_size=3))
def test_moving_world_frame_leaves_scores_unchanged(seed, yaw, shift):
    """Re-expressing the truth in another horizontal world frame does not change any score."""
    rng = np.random.default_rng(seed)
    truth = _truth(rng)
    est = _perfect(truth)
    noisy = Estimate(est.reference, tuple(
        EstimateStep(s.t, {n: PlanarPose(q.p + rng.normal(0, 0.1, 3), q.theta + rng.normal(0, 0.2))
                           for n, q in s.poses.items()}) for s in est.steps), {})
    a = score_estimate(truth, noisy).to_dict()
    b = score_estimate(_moved(truth, yaw, np.asarray(shift)), noisy).to_dict()
    for name in ("A1", "A2"):
        for key in ("position_m", "relative_position_pct", "yaw_deg", "coverage"):
            assert b["assemblies"][name][key] == pytest.approx(a["assemblies"][name][key], rel=1e-9, abs=1e-9)


def test_yaw_error_is_wrapped():
    """A yaw off by 2 pi scores 0 deg, one off by 350 deg scores 10 deg."""
    truth = _truth(np.random.default_rng(1), names=("A0", "A1"))
    est = _perfect(truth)
    turned = Estimate("A0", tuple(EstimateStep(s.t, {"A1": PlanarPose(s.poses["A1"].p, s.poses["A1"].theta + 2 * np.pi)})
                                  for s in est.steps), {})
    assert score_estimate(truth, turned).overall.yaw_deg == pytest.approx(0, abs=1e-9)
    off = Estimate("A0", tuple(EstimateStep(s.t, {"A1": PlanarPose(s.poses["A1"].p, s.poses["A1"].theta + np.radians(350))})
                               for s in est.steps), {})
    assert score_estimate(truth, off).overall.yaw_deg == pytest.approx(10.0)


def test_relative_error_divides_by_true_distance():
    """A 0.1 m error on a target 2 m away is a 5 % relative error."""
    times = np.array([0.0])
    eye = np.eye(3)[None]
    truth = GroundTruth(times, {"A0": eye, "A1": eye}, {"A0": np.zeros((1, 3)), "A1": np.array([[2.0, 0, 0]])})
    est = Estimate("A0", (EstimateStep(0.0, {"A1": PlanarPose(np.array([2.0, 0.1, 0]), 0.0)}),), {})
    s = score_estimate(truth, est).overall
    assert s.position_m == pytest.approx(0.1)
    assert s.relative_position_pct == pytest.approx(5.0)


def test_coverage_counts_placed_steps_and_never_nan():
    """Steps an assembly is left out of lower its coverage; nothing placed gives None, not NaN."""
    truth = _truth(np.random.default_rng(2), T=4, names=("A0", "A1", "A2"))
    est = _perfect(truth, skip={("A1", 0), ("A1", 1)} | {("A2", k) for k in range(4)})
    score = score_estimate(truth, est)
    assert score.per_assembly["A1"].coverage == 0.5
    assert score.per_assembly["A2"].placed == 0
    assert score.per_assembly["A2"].position_m is None and score.per_assembly["A2"].yaw_deg is None
    assert score.overall.coverage == pytest.approx(2 / 8)


def test_steps_at_unknown_times_are_counted_unmatched():
    """Estimate steps whose time is in no truth step are not scored but counted."""
    truth = _truth(np.random.default_rng(3), T=3)
    est = _perfect(truth)
    est = Estimate("A0", est.steps + (EstimateStep(99.0, est.steps[0].poses),), {})
    assert score_estimate(truth, est).unmatched_steps == 1


def test_unknown_reference_is_bad_input():
    """An estimate relative to an assembly the truth does not know raises InputError."""
    truth = _truth(np.random.default_rng(4))
    with pytest.raises(InputError):
        score_estimate(truth, Estimate("B9", (), {}))


def test_estimate_gap_reports_largest_differences_and_mismatched_placements():
    """estimate_gap: max position and wrapped yaw difference over shared placements, plus one-sided ones."""
    from decentral.metrics import estimate_gap

    a = Estimate("A0", (EstimateStep(0.0, {"A1": PlanarPose(np.array([1.0, 0, 0]), 3.1)}),
                        EstimateStep(0.2, {"A1": PlanarPose(np.zeros(3), 0.0), "A2": PlanarPose(np.zeros(3), 0.0)})), {})
    b = Estimate("A0", (EstimateStep(0.0, {"A1": PlanarPose(np.array([1.0, 0.002, 0]), -3.1)}),
                        EstimateStep(0.2, {"A1": PlanarPose(np.zeros(3), 0.0)})), {})
    dp, dth, mismatched = estimate_gap(a, b)
    assert dp == pytest.approx(0.002) and dth == pytest.approx(2 * np.pi - 6.2) and mismatched == 1
