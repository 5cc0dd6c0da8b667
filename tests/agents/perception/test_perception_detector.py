"""The classical circle detector: accuracy on clean and occluded discs, and degenerate frames."""

import numpy as np
import pytest

from agents.perception import HoughCircleDetector
from agents.perception.hough import suppress
from agents.perception.types import Circle
from perception_scenes import H, W, frame, layout
from sims.lab.experiments.synthetic_scene import Bar, SceneNode


def _match(circles, node, tol=0.3):
    near = [c for c in circles if np.hypot(c.u - node.u, c.v - node.v) < tol * node.r]
    return min(near, key=lambda c: np.hypot(c.u - node.u, c.v - node.v)) if near else None


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_clean_discs_within_one_pixel_and_three_percent(seed):
    """On clean frames every disc is found, centre within 1 px and radius within 3 %."""
    nodes = layout(seed)
    circles = HoughCircleDetector().detect(frame(nodes, seed=seed))
    for n in nodes:
        c = _match(circles, n)
        assert c is not None, f"disc at ({n.u:.0f}, {n.v:.0f}) r={n.r:.0f} missed"
        assert np.hypot(c.u - n.u, c.v - n.v) < 1.0
        assert abs(c.r - n.r) / n.r < 0.03


def test_no_false_circles_beside_the_discs():
    """Every returned circle on a clean frame belongs to a disc (no circle inscribed in a sticker)."""
    nodes = layout(3)
    circles = HoughCircleDetector().detect(frame(nodes, seed=3))
    assert all(_match([c], n) is not None for c in circles for n in [min(nodes, key=lambda n: np.hypot(c.u - n.u, c.v - n.v))])


def test_disc_crossed_by_a_strut_stays_accurate():
    """A bar across a disc (a strut in front) leaves its centre within 1.5 px and radius within 4 %."""
    n = SceneNode(320, 240, 40, tag=7, tag_size=0.7)
    img = frame([n], bars=[Bar((250, 200), (400, 270), width=12)])
    c = _match(HoughCircleDetector().detect(img), n)
    assert c is not None
    assert np.hypot(c.u - n.u, c.v - n.v) < 1.5 and abs(c.r - n.r) / n.r < 0.04


def test_blurred_noisy_discs_stay_within_two_pixels():
    """With noise sigma 4 and blur sigma 1 the discs are still found within 2 px and 6 %."""
    nodes = layout(4)
    circles = HoughCircleDetector().detect(frame(nodes, noise=4.0, blur=1.0, seed=4))
    for n in nodes:
        c = _match(circles, n)
        assert c is not None
        assert np.hypot(c.u - n.u, c.v - n.v) < 2.0 and abs(c.r - n.r) / n.r < 0.06


def test_empty_uniform_frame_gives_no_circle():
    """A uniform grey frame yields no circle and no error."""
    assert HoughCircleDetector().detect(np.full((H, W, 3), 128, np.uint8)) == []


def test_floor_only_frame_gives_no_circle():
    """The textured floor alone yields no circle."""
    assert HoughCircleDetector().detect(frame([])) == []


def test_grey_and_colour_inputs_agree():
    """A grey image and its BGR copy give the same circles within 0.3 px."""
    import cv2

    img = frame(layout(5), seed=5)
    a = HoughCircleDetector().detect(img)
    b = HoughCircleDetector().detect(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))
    assert len(a) == len(b)
    for c in a:
        assert min(np.hypot(c.u - d.u, c.v - d.v) for d in b) < 0.3


def test_suppression_drops_the_circle_inside_a_strong_one():
    """Of two nested circles, the strong outer one is kept and the inner one dropped."""
    outer, inner = Circle(100, 100, 40, 0.8), Circle(102, 99, 15, 0.9)
    assert suppress([inner, outer]) == [outer]


def test_suppression_keeps_separate_circles():
    """Circles whose centres lie outside each other both survive."""
    a, b = Circle(100, 100, 30, 0.6), Circle(160, 100, 30, 0.7)
    assert set(suppress([a, b])) == {a, b}
