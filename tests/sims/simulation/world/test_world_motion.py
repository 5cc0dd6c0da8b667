"""Properties of the root trajectories in sims.simulation.world.motion."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from sims.simulation.world.motion import jitter, still, wander_many


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_jitter_stays_within_its_amplitude(seed):
    """Jitter keeps the root within the amplitude of its start, and the heading within its own."""
    xy, yaw = jitter(200, 0.2, (1.0, 2.0), 0.5, np.random.default_rng(seed), amplitude=0.1, yaw_amplitude=0.2)
    assert np.all(np.abs(xy - [1.0, 2.0]) <= 0.1 + 1e-12)
    assert np.all(np.abs(yaw - 0.5) <= 0.2 + 1e-12)
    assert np.allclose(xy[0], [1.0, 2.0]) and yaw[0] == 0.5


def test_wander_is_smooth_at_constant_speed():
    """Wandering roots move at the set speed with bounded heading rate (no jumps)."""
    rng = np.random.default_rng(0)
    (xy, yaw), = wander_many(300, 0.2, [(0, 0, 0)], [(0, 0)], rng, speed=0.1)
    step = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    assert np.allclose(step, 0.1 * 0.2, rtol=0.02)
    assert np.max(np.abs(np.diff(yaw))) <= 0.1 * 0.2 * 4.0 + 1e-9


def test_wander_stays_near_home_and_apart():
    """Roots wander around their homes and keep some distance from each other."""
    rng = np.random.default_rng(1)
    paths = wander_many(400, 0.2, [(0, 0, 0), (1.0, 0, 3.0)], [(0, 0), (1.0, 0)], rng, radius=0.3, clearance=0.6)
    for (xy, _), home in zip(paths, [(0, 0), (1.0, 0)]):
        assert np.max(np.linalg.norm(xy - home, axis=1)) < 1.0
    gap = np.linalg.norm(paths[0][0] - paths[1][0], axis=1)
    assert gap.min() > 0.25


def test_still_never_moves():
    """A still root has the same pose at every step."""
    xy, yaw = still(5, (1, 2), 0.3)
    assert np.all(xy == [1, 2]) and np.all(yaw == 0.3)
