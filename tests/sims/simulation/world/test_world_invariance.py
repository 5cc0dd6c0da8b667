"""The simulated observations are relative: moving the whole world leaves the log unchanged."""

from dataclasses import replace

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from sims.simulation.scenarios import get_scenario


def _observe(scenario, world, seed):
    sensors = scenario.reset(world, seed)
    return [scenario.observe(world, k, sensors) for k in range(world.steps)]


def _moved(world, yaw, shift):
    c, s = np.cos(yaw), np.sin(yaw)
    R = np.array([[c, -s], [s, c]])
    tracks = tuple(replace(a, xy=a.xy @ R.T + shift, yaw=a.yaw + yaw) for a in world.assemblies)
    return replace(world, assemblies=tracks)


@settings(max_examples=6, deadline=None)
@given(st.sampled_from(["table1", "multi", "reconfig"]), st.floats(-np.pi, np.pi),
       st.lists(st.floats(-20, 20), min_size=2, max_size=2), st.integers(0, 1000))
def test_moving_the_world_frame_leaves_the_log_unchanged(name, yaw, shift, seed):
    """A planar rigid motion of every assembly changes no detection, odometry or configuration."""
    scenario = get_scenario(name, steps=8)
    world = scenario.make_world(np.random.default_rng(seed))
    a = _observe(scenario, world, seed)
    b = _observe(scenario, _moved(world, yaw, np.asarray(shift)), seed)
    for sa, sb in zip(a, b):
        assert set(sa.odometry) == set(sb.odometry)
        for name_ in sa.odometry:
            assert np.allclose(sa.odometry[name_].dp, sb.odometry[name_].dp, atol=1e-9)
            assert abs(np.angle(np.exp(1j * (sa.odometry[name_].dtheta - sb.odometry[name_].dtheta)))) < 1e-9
        for key in sa.detections:
            da = sorted((d.node, d.u, d.v, d.r) for d in sa.detections[key])
            db = sorted((d.node, d.u, d.v, d.r) for d in sb.detections[key])
            assert [x[0] for x in da] == [x[0] for x in db]
            assert np.allclose(np.array([x[1:] for x in da]).reshape(-1, 3), np.array([x[1:] for x in db]).reshape(-1, 3),
                               atol=1e-6)
