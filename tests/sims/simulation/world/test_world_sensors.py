"""Properties of the simulated sensors in sims.simulation.world.sensors."""

from dataclasses import replace

import numpy as np
import pytest

from sims.simulation.scenarios import get_scenario, simulate
from sims.simulation.world.sensors import STRAY_ID_BASE, SensorNoise, detections_at, odometry_at, sensor_streams


def _world(**params):
    scenario = get_scenario("table1", steps=12, **params)
    return scenario, scenario.make_world(np.random.default_rng(0))


def test_noiseless_odometry_is_the_true_relative_motion():
    """Composing exact odometry onto the previous root pose gives the current root pose (seed eq. (6))."""
    _, world = _world()
    rng = np.random.default_rng(0)
    for name in ("A0", "A1"):
        for k in range(1, world.steps):
            odo = odometry_at(world, name, k, SensorNoise.none(), rng)
            prev, cur = world.root_pose(name, k - 1), world.root_pose(name, k)
            assert np.allclose(prev.R @ odo.dp + prev.p, cur.p)
            yaw = np.arctan2(cur.R[1, 0], cur.R[0, 0]) - np.arctan2(prev.R[1, 0], prev.R[0, 0])
            assert np.angle(np.exp(1j * (odo.dtheta - yaw))) == pytest.approx(0, abs=1e-12)


def test_noise_streams_depend_only_on_seed_and_name():
    """A source's stream is the same whatever other sources exist."""
    a = sensor_streams(7, ["A0/cam0"])["A0/cam0"].random(5)
    b = sensor_streams(7, ["X/cam9", "A0/cam0", "odometry/A1"])["A0/cam0"].random(5)
    c = sensor_streams(8, ["A0/cam0"])["A0/cam0"].random(5)
    assert np.array_equal(a, b) and not np.array_equal(a, c)


def test_noiseless_detections_are_the_visible_truth():
    """Without noise every visible node is detected exactly at its true circle."""
    _, world = _world()
    for k in range(world.steps):
        dets, visible = detections_at(world, k, SensorNoise.none(), sensor_streams(0, ["A0/cam0"]))
        got = sorted((d.node, d.u, d.v, d.r) for d in dets["A0/cam0"])
        want = sorted((v["id"], v["u"], v["v"], v["r"]) for v in visible["A0/cam0"])
        assert got == want


def test_full_dropout_detects_nothing():
    """Drop-out probability 1 leaves every frame empty."""
    _, world = _world()
    noise = replace(SensorNoise(), dropout=1.0)
    dets, visible = detections_at(world, 3, noise, sensor_streams(0, ["A0/cam0"]))
    assert visible["A0/cam0"] and not dets["A0/cam0"]


def test_stray_tags_belong_to_no_assembly():
    """Stray detections carry ids that no assembly has."""
    sim = simulate(get_scenario("table1", steps=20, stray_rate=2.0), seed=1)
    ids = {n for step in sim.log.steps for nodes in step.config.values() for n in nodes}
    strays = [d for s in sim.log.steps for d in s.detections["A0/cam0"] if d.node >= STRAY_ID_BASE]
    assert strays and not ({d.node for d in strays} & ids)


def test_wrong_ids_name_other_real_nodes():
    """With wrong-id probability 1 every detection names a real node, but not the one at its circle."""
    sim = simulate(get_scenario("table1", steps=10, wrong_id=1.0, dropout=0.0), seed=2)
    checked = 0
    for step, vis in zip(sim.log.steps, sim.truth.visible):
        truth = vis["A0/cam0"]
        for d in step.detections["A0/cam0"]:
            nearest = min(truth, key=lambda v: np.hypot(v["u"] - d.u, v["v"] - d.v))
            assert d.node in step.node_owner() and d.node != nearest["id"]
            checked += 1
    assert checked > 0


def test_missing_odometry_is_left_out():
    """With missing probability 1 no step carries odometry."""
    sim = simulate(get_scenario("table1", steps=10, odom_missing=1.0), seed=0)
    assert all(not s.odometry for s in sim.log.steps)


def test_noise_model_rejects_bad_values():
    """Negative stds and probabilities above 1 are refused."""
    with pytest.raises(ValueError):
        SensorNoise(pixel_sigma=-1.0)
    with pytest.raises(ValueError):
        SensorNoise(dropout=1.5)
