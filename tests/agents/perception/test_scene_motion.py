"""The scene pieces shared by the varied and the harder scene generators: struts, looks, motion."""

import numpy as np
import pytest

from sims.lab.experiments.varied_scenes import Mover, Sphere, animate, random_look, random_struts

W, H = 64, 48


def test_struts_keep_to_their_count_width_and_grey_ranges():
    """Every strut set has a count in the inclusive range, widths and greys inside theirs."""
    counts = set()
    for seed in range(40):
        struts = random_struts(np.random.default_rng(seed), W, H, count=(1, 3), spread=20, widths=(4, 20),
                               greys=(0.1, 0.85))
        counts.add(len(struts))
        for st, vel in struts:
            assert 4 <= st.width <= 20 and 0.1 <= st.colour[0] <= 0.85 and st.colour[0] == st.colour[1]
            assert vel.shape == (2,)
    assert counts == {1, 2, 3}


def test_look_keeps_to_its_ranges():
    """A drawn look's fields lie in the ranges asked for, its light above the image plane."""
    for seed in range(20):
        look = random_look(np.random.default_rng(seed), elevation=(0.25, 1.3), noise=(1.0, 9.0), jpeg=(0, 50))
        assert 1.0 <= look.noise <= 9.0 and look.jpeg in (0, 50)
        assert np.sin(0.25) <= look.light[2] <= np.sin(1.3) and np.isclose(np.linalg.norm(look.light), 1.0)


@pytest.mark.parametrize(("margin", "turned"), [(1.0, True), (5.0, False)])
def test_a_sphere_turns_back_only_beyond_the_margin(margin, turned):
    """A sphere 2 radii left of the frame, moving left, turns back with a 1-radius margin, not with a 5-radius one."""
    r = 5.0
    mover = Mover(Sphere(0, -2 * r, H / 2, r, (0.5, 0.5, 0.5), tag=False), np.array([-1.0, 0.0]), r, 0.0,
                  np.array([0.0, 0.0, 1.0]), 0.0)
    floor = np.full((H, W, 3), 0.5, np.float32)
    frames = animate([mover], [], random_look(np.random.default_rng(0)), floor, np.ones((H, W), np.float32),
                     np.random.default_rng(1), np.random.default_rng(2), 1, radius=(1.0, 50.0), jitter=0.0,
                     wobble=0.0, margin=margin)
    assert len(frames) == 1 and frames[0].image.shape == (H, W, 3)
    assert (mover.vel[0] > 0) == turned
