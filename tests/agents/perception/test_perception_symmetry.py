"""The symmetry detector (`detector="symmetry"`): colour-edge votes for circle centres, then the rim."""

import cv2
import numpy as np
import pytest

from agents.perception import make_detector
from agents.perception.symmetry import radius_ladder, symmetry_candidates
from agents.perception.symmetry_detector import SymmetryCircleDetector


def _disc(colour_left, colour_right, background=(128, 128, 128), centre=(160, 120), r=40, noise=2.0, seed=0):
    """A 320 x 240 BGR frame with a disc whose left and right halves have their own colours."""
    img = np.zeros((240, 320, 3), np.float32)
    img[:] = background
    yy, xx = np.mgrid[0:240, 0:320]
    inside = (xx - centre[0]) ** 2 + (yy - centre[1]) ** 2 <= r * r
    img[inside & (xx < centre[0])] = colour_left
    img[inside & (xx >= centre[0])] = colour_right
    img = cv2.GaussianBlur(img, (0, 0), 0.8) + np.random.default_rng(seed).normal(0, noise, img.shape)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def test_radius_ladder_windows_meet():
    """Neighbouring radii of the ladder are as far apart as their +-window tolerances reach, and it spans the range."""
    lad = radius_ladder(4.0, 50.0, 0.1)
    assert lad[0] == 4.0 and lad[-1] >= 50.0 and lad[-2] < 50.0
    np.testing.assert_allclose(lad[1:] * (1 - 0.1), lad[:-1] * (1 + 0.1))


def test_votes_peak_at_a_disc_darker_on_one_side_and_brighter_on_the_other():
    """A disc whose halves step down and up against the floor still gets one strong candidate at its centre."""
    img = _disc((80, 80, 80), (180, 180, 180))
    cand = symmetry_candidates(img, radius_ladder(20.0, 60.0, 0.1))
    u, v, r, support = cand[0]
    assert np.hypot(u - 160, v - 120) <= 2.0 and abs(r - 40) <= 0.12 * 40 and support > 0.6


def test_a_disc_as_bright_as_the_floor_but_of_another_hue_is_found():
    """A disc of the floor's grey level (within 3 levels) but another hue gives a circle on its rim."""
    colour = (200, 100, 144)  # BGR; grey 0.114 B + 0.587 G + 0.299 R = 125.6 on a floor of 128
    img = _disc(colour, colour)
    grey = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY).astype(float)
    assert abs(grey[120, 160] - grey[10, 10]) <= 6
    circles = SymmetryCircleDetector().detect(img)
    assert circles, "no circle"
    c = circles[0]
    assert np.hypot(c.u - 160, c.v - 120) <= 2.0 and abs(c.r - 40) <= 0.05 * 40, c


def test_grey_images_and_empty_images_are_accepted():
    """A grey (H, W) frame gives the same kind of circle; an empty frame none; a 2-channel one is refused."""
    img = cv2.cvtColor(_disc((70, 70, 70), (70, 70, 70)), cv2.COLOR_BGR2GRAY)
    circles = SymmetryCircleDetector().detect(img)
    assert circles and abs(circles[0].r - 40) <= 2.0
    assert SymmetryCircleDetector().detect(np.zeros((0, 0, 3), np.uint8)) == []
    with pytest.raises(ValueError, match="image"):
        SymmetryCircleDetector().detect(np.zeros((20, 20, 2), np.uint8))


def test_make_detector_builds_the_symmetry_detector_with_its_radius_range():
    """make_detector("symmetry", lo, hi) builds a SymmetryCircleDetector for radii [floor(lo), ceil(hi)]."""
    det = make_detector("symmetry", 10.2, 90.5)
    assert isinstance(det, SymmetryCircleDetector)
    assert (det.config.min_radius, det.config.max_radius) == (10, 91)


def test_weak_rim_is_kept_with_a_faint_print_inside_but_not_around_plain_floor():
    """A circle short of the score threshold is kept when a print of 70 grey levels contrast lies inside it
    (a small rendered node whose struts hide part of its rim), and dropped around a plain patch."""
    det = SymmetryCircleDetector()
    img = np.full((200, 300, 3), 120.0, np.float32)
    yy, xx = np.mgrid[0:200, 0:300]
    print_ = (np.hypot(xx - 80, yy - 100) < 18) & (((xx // 5) + (yy // 5)) % 2 == 0)
    img[print_] -= 70.0  # the print's dark cells, as blurred on a 25 px node
    circles = np.array([[80.0, 100.0, 25.0], [220.0, 100.0, 25.0]])
    scores = np.array([0.4, 0.4])
    assert scores[0] < det._threshold(circles)[0]
    assert det._accepted(img, circles, scores).tolist() == [True, False]


def test_repeats_of_one_rim_keep_the_better_circle_but_a_rim_and_its_tag_both_go_on():
    """Of two circles 8 % apart the better scored is kept unless the larger scores at least 0.9 of it;
    a circle half the size inside (a tag) is no repeat and is left for the suppression."""
    from agents.perception.symmetry_detector import _merge_repeats

    circles = np.array([[100.0, 100.0, 20.0], [100.5, 100.0, 21.6], [100.0, 100.0, 10.0]])
    kept, _ = _merge_repeats(circles, np.array([0.9, 0.7, 0.8]), 0.2, 0.9)
    assert sorted(kept[:, 2].tolist()) == [10.0, 20.0]
    kept, _ = _merge_repeats(circles, np.array([0.9, 0.85, 0.8]), 0.2, 0.9)
    assert sorted(kept[:, 2].tolist()) == [10.0, 21.6]
