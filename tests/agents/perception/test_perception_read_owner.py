"""A tag read stays only on the circle that must own it (agents.perception.read_owner)."""

import numpy as np
import pytest

from agents.perception import Perception
from agents.perception.read_owner import PrintScale, print_fraction, unambiguous_reads
from agents.perception.types import Circle, TagRead


def _tag(tag, u, v, half):
    """A read of ``tag`` whose square print of half-side ``half`` is centred on (u, v)."""
    corners = np.array([[u - half, v - half], [u + half, v - half], [u + half, v + half], [u - half, v + half]])
    return TagRead(tag, tag, corners, 0, 50.0, 1.0)


# a near sphere (r 60) in front of a farther one (r 40) whose disc it overlaps from the right
NEAR, FAR = Circle(300.0, 200.0, 60.0, 0.9), Circle(220.0, 200.0, 40.0, 0.9)


def test_read_in_the_overlap_goes_to_the_nearer_circle_only():
    """A print centred where two discs overlap is kept on the larger (nearer) circle and dropped from the other."""
    read = _tag(5, 250.0, 200.0, 8.0)  # inside both discs
    out = unambiguous_reads([NEAR, FAR], [read, read])
    assert out[0] is read and out[1] is None


def test_read_on_the_visible_part_of_the_farther_circle_is_kept():
    """A print wholly on the part of the farther disc that the nearer one does not cover stays with it."""
    read = _tag(6, 200.0, 200.0, 10.0)  # 100 px from NEAR's centre: outside its disc
    out = unambiguous_reads([NEAR, FAR], [None, read])
    assert out == [None, read]


def test_read_with_a_corner_outside_its_circle_is_dropped():
    """A print reaching well beyond the circle (by more than the slack) is not the circle's own."""
    c = Circle(100.0, 100.0, 20.0, 0.9)
    inside, outside = _tag(3, 100.0, 100.0, 10.0), _tag(3, 110.0, 100.0, 14.0)  # corner at 29 px > 1.2 r + 1
    assert unambiguous_reads([c], [inside]) == [inside]
    assert unambiguous_reads([c], [outside]) == [None]


def test_two_circles_of_equal_size_sharing_a_read_keep_neither():
    """Where neither circle is clearly nearer (radii within the margin), a print covered by both is nobody's."""
    a, b = Circle(100.0, 100.0, 30.0, 0.9), Circle(140.0, 100.0, 29.5, 0.9)
    read = _tag(9, 120.0, 100.0, 4.0)
    assert unambiguous_reads([a, b], [read, read]) == [None, None]


def test_same_tag_on_two_separate_circles_is_dropped_from_both():
    """One tag cannot be printed on two nodes: two disjoint circles reading it both lose the read."""
    a, b = Circle(100.0, 100.0, 30.0, 0.9), Circle(300.0, 100.0, 30.0, 0.9)
    ra, rb, other = _tag(4, 100.0, 100.0, 8.0), _tag(4, 300.0, 100.0, 8.0), _tag(8, 300.0, 100.0, 8.0)
    assert unambiguous_reads([a, b], [ra, rb]) == [None, None]
    assert unambiguous_reads([a, b], [ra, other]) == [ra, other]


def test_lengths_must_agree():
    """Circles and reads of different lengths are refused."""
    with pytest.raises(ValueError):
        unambiguous_reads([NEAR], [])


class _SameReadEverywhere:
    """An identifier reading one print (centred in the overlap of NEAR and FAR) inside every circle."""

    def identify(self, image, circles):
        return [_tag(5, 250.0, 200.0, 8.0) for _ in circles]


class _Fixed:
    def detect(self, image):
        return [FAR, NEAR]  # the farther first: without the rule the tracker would give it the id


@pytest.mark.parametrize("track", [False, True])
def test_perception_shows_an_overlap_read_only_on_the_nearer_node(track):
    """Through the front end (with or without tracking) the shared read names the nearer node only."""
    p = Perception(_Fixed(), _SameReadEverywhere(), track=track, motion=None)
    dets, _ = p.process(np.zeros((400, 500, 3), np.uint8))
    assert [d.node for d in dets] == [None, 5]


def _reads_at(fractions, r=40.0):
    """One circle of radius ``r`` per fraction, each with a square print whose side is ``fraction * r``."""
    circles = [Circle(100.0 * k, 100.0, r, 0.9) for k in range(len(fractions))]
    return circles, [_tag(k, c.u, c.v, f * r / 2) for k, (c, f) in enumerate(zip(circles, fractions))]


def test_print_fraction_is_the_longest_side_over_the_radius():
    circles, reads = _reads_at([0.6])
    assert print_fraction(circles[0], reads[0]) == pytest.approx(0.6)


def test_print_scale_drops_a_print_far_too_small_or_large_for_its_circle_once_it_has_seen_enough():
    """After 8 reads of fractions 0.45-0.93 (prints of several sizes, as on the tuning scenes), a print a quarter of a
    radius (a circle drawn around two spheres) and one of 1.6 radii (a circle around the print) are dropped; the
    usual sizes still pass; before 8 reads nothing is dropped; reset forgets."""
    scale = PrintScale()
    circles, reads = _reads_at([0.25, 1.6])
    assert scale.filter(circles, reads) == reads  # nothing learnt yet: both kept (and learnt)
    scale.reset()
    assert scale.median() is None
    usual = [0.45, 0.55, 0.6, 0.65, 0.66, 0.7, 0.8, 0.93]
    circles, reads = _reads_at(usual)
    assert scale.filter(circles, reads) == reads
    assert scale.median() == pytest.approx(0.655)
    circles, reads = _reads_at([0.25, 1.6, 0.45, 0.93, 0.66])
    assert scale.filter(circles, reads) == [None, None, *reads[2:]]
    assert scale.filter(circles, [None] * 5) == [None] * 5
    scale.reset()
    assert scale.filter(circles[:2], reads[:2]) == reads[:2]


def test_print_scale_forgets_old_reads_and_follows_a_camera_that_changes():
    """Only the last ``keep`` reads count: after many reads of another print size, that size is the usual one."""
    scale = PrintScale(keep=16)
    scale.filter(*_reads_at([0.6] * 16))
    for f in (0.9, 1.0, 1.1, 1.15):  # each step within a factor 2 of the median so far
        scale.filter(*_reads_at([f] * 16))
    assert scale.median() == pytest.approx(1.15)
    circles, reads = _reads_at([0.5])
    assert scale.filter(circles, reads) == [None]


def test_print_scale_refuses_a_meaningless_band():
    with pytest.raises(ValueError):
        PrintScale(factor=1.0)


def test_print_scale_drops_a_read_it_cannot_measure():
    """A read on a circle of no radius, with corners that are not numbers or all in one place, is dropped and not learnt."""
    scale = PrintScale()
    read = _tag(1, 10.0, 10.0, 4.0)
    assert scale.filter([Circle(10.0, 10.0, 0.0, 0.9)], [read]) == [None]
    bad = TagRead(2, 2, np.full((4, 2), np.nan), 0, 50.0, 1.0)
    assert scale.filter([Circle(10.0, 10.0, 20.0, 0.9)], [bad]) == [None]
    point = TagRead(3, 3, np.zeros((4, 2)), 0, 50.0, 1.0)  # four corners in one place: a print of no size
    assert scale.filter([Circle(10.0, 10.0, 20.0, 0.9)], [point]) == [None]
    scale.filter(*_reads_at([0.6] * 8))
    assert scale.median() == pytest.approx(0.6)  # (neither unmeasurable read was learnt)


def test_the_print_rule_is_on_for_a_detector_of_sphere_outlines_only():
    """Perception applies PrintScale where the detector's circles are the spheres' outlines (the learned one), not
    for hough (whose circle is sometimes the print itself), unless asked."""
    assert isinstance(Perception("learned").print_scale, PrintScale)
    assert Perception("hough").print_scale is None
    assert isinstance(Perception("hough", print_scale=PrintScale()).print_scale, PrintScale)
    assert Perception("learned", print_scale=None).print_scale is None
