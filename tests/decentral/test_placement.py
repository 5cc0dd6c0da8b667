"""Every assembly an estimate leaves out carries the reason, in both the centralized and the ADMM run."""

import numpy as np

from decentral.estimator import EstimatorConfig, estimate_log
from decentral.unplaced import REASONS, count_reasons, unplaced_reasons
from sims.runners.admm_run import run_admm
from sims.simulation.scenarios import get_scenario, simulate
from tests.synthetic import camera, circle_motion, l_config, line_config, make_log

N = 6


def split_scene():
    """A0 sees A1; A2 (behind A0, facing away) sees A3; A4 is seen by nobody and sees nothing."""
    world = {
        "A0": [(0.0, np.array([0.02 * k, 0.0, 0.81])) for k in range(N)],
        "A1": circle_motion(N, (2.0, 0.0), 0.3, 0.0, 0.05, 0.06),
        "A2": [(np.pi, np.array([-4.0, 0.0, 0.81])) for _ in range(N)],
        "A3": circle_motion(N, (-6.0, 0.0), 0.3, 1.0, 0.05, 0.06),
        "A4": [(0.0, np.array([0.0, 10.0, 0.06])) for _ in range(N)],
    }
    configs = {"A0": line_config([0, 1]), "A1": l_config([5, 6, 7]), "A2": line_config([10, 11]),
               "A3": l_config([20, 21, 22]), "A4": line_config([30, 31])}
    return make_log(world, configs, [camera("A0"), camera("A2")])


def test_reasons_name_each_failed_condition_in_order():
    """The first failed condition is the reason: data, connection, solver, yaw observability, yaw std."""
    kw = dict(with_data={"B", "C", "D", "E", "F"}, connected={"C", "D", "E", "F"}, solved=True,
              yaw_std={"D": 2.0, "F": 0.1})
    why = unplaced_reasons(["R", "A", "B", "C", "D", "F"], "R", {"F"}, **kw)
    assert why == {"A": "no_data", "B": "not_connected", "C": "yaw_unobservable", "D": "yaw_std_above_limit"}
    assert set(why.values()) <= set(REASONS)
    assert unplaced_reasons(["R", "C"], "R", (), **{**kw, "solved": False}) == {"C": "solver_failed"}


def test_centralized_estimate_says_why_each_assembly_is_missing():
    """A1 placed; A3 seen only by A2 is not connected; A2 and A4 without visual ties to A0 likewise or no data."""
    est = estimate_log(split_scene(), EstimatorConfig(window=3))
    for step in est.steps:
        assert "A1" in step.poses
        assert step.unplaced == {"A2": "not_connected", "A3": "not_connected", "A4": "no_data"}
        assert set(step.poses).isdisjoint(step.unplaced)
    assert est.stats["unplaced"] == {"no_data": N, "not_connected": 2 * N}


def test_a_tight_yaw_limit_is_reported_as_such():
    """With max_yaw_std far below any achievable std every connected target is 'yaw_std_above_limit'."""
    est = estimate_log(split_scene(), EstimatorConfig(window=3, max_yaw_std=1e-9))
    assert all(step.unplaced["A1"] == "yaw_std_above_limit" for step in est.steps)
    assert est.stats["unplaced"]["yaw_std_above_limit"] == N


def test_one_node_target_is_yaw_unobservable_in_both_modes():
    """single_node (noiseless): a still one-node target is reported 'yaw_unobservable' by both modes."""
    sim = simulate(get_scenario("single_node", steps=6, noise=False), seed=0)
    central = estimate_log(sim.log, EstimatorConfig(window=3))
    admm = run_admm(sim.log).estimate
    for est in (central, admm):
        assert all(not step.poses for step in est.steps)
        assert all(step.unplaced == {"A1": "yaw_unobservable"} for step in est.steps[1:])
        assert est.stats["unplaced"] == count_reasons(step.unplaced for step in est.steps)


def test_admm_reasons_match_the_centralized_ones():
    """With every agent's forms shared, the reference agent gives the centralized reasons step by step."""
    log = split_scene()
    central = estimate_log(log, EstimatorConfig(window=3))
    from sims.runners.admm_run import AdmmRunConfig

    admm = run_admm(log, config=AdmmRunConfig(window=3, max_rounds=30)).estimate  # A2, A3 never settle
    for a, b in zip(central.steps[1:], admm.steps[1:]):
        assert a.unplaced == b.unplaced


def test_bearing_baseline_says_why_too():
    """The bearing baseline lists targets the reference never sees as 'no_data'."""
    from decentral.bearing import BearingConfig, estimate_log_bearing

    est = estimate_log_bearing(split_scene(), BearingConfig(window=3))
    for step in est.steps:
        assert step.unplaced.get("A4") == "no_data" and set(step.poses).isdisjoint(step.unplaced)
    assert est.stats["unplaced"] == count_reasons(step.unplaced for step in est.steps)
