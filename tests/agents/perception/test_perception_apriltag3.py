"""The AprilTag 3 library inside each circle: the default tag reader, its filters and corner order."""

import numpy as np
import pytest

pytest.importorskip("pupil_apriltags", reason="the AprilTag 3 binding (pupil-apriltags) is a core dependency")

from agents.perception import AprilTagIdentifier, Perception  # noqa: E402
from agents.perception.apriltag3 import AprilTag3Config, AprilTag3Identifier, make_identifier  # noqa: E402
from agents.perception.types import Circle, Identifier  # noqa: E402
from perception_scenes import frame, layout  # noqa: E402
from sims.lab.experiments.synthetic_scene import SceneNode  # noqa: E402


def _circles(nodes):
    return [Circle(n.u, n.v, n.r, 1.0) for n in nodes]


def test_default_reader_is_apriltag3_and_meets_the_protocol():
    """make_identifier() and Perception() use the AprilTag 3 reader, an Identifier."""
    ident = make_identifier()
    assert isinstance(ident, AprilTag3Identifier) and isinstance(ident, Identifier)
    assert isinstance(Perception().identifier, AprilTag3Identifier)


def test_tag_ids_recovered_on_clean_frames():
    """Every tag on clean 22-45 px discs is read with its id by the library alone (no fallback)."""
    nodes = layout(0)
    reads = AprilTag3Identifier(AprilTag3Config(fallback=False)).identify(frame(nodes), _circles(nodes))
    assert [r.node if r else None for r in reads] == [n.tag for n in nodes]


def test_noisy_frames_give_no_wrong_id():
    """With noise sigma 8 and blur, reads may fail but are never wrong."""
    nodes = layout(1, count=6)
    reads = make_identifier().identify(frame(nodes, noise=8.0, blur=0.8, seed=1), _circles(nodes))
    assert all(r is None or r.tag == n.tag for r, n in zip(reads, nodes))
    assert sum(r is not None for r in reads) >= 3


def test_discs_without_tags_and_empty_lists_give_no_read():
    """Tagless discs give None per circle; no circles give no reads."""
    nodes = [SceneNode(n.u, n.v, n.r) for n in layout(2)]
    ident = make_identifier()
    assert ident.identify(frame(nodes), _circles(nodes)) == [None] * len(nodes)
    assert ident.identify(frame([]), []) == []


def test_corners_in_the_canonical_order_of_opencvs_reader():
    """The corners match OpenCV's reader's (top-left, top-right, bottom-right, bottom-left) within 3 px."""
    nodes = [SceneNode(320, 240, 60, tag=42, tag_size=0.8)]
    img = frame(nodes)
    (ours,) = AprilTagIdentifier().identify(img, _circles(nodes))
    (at3,) = AprilTag3Identifier(AprilTag3Config(fallback=False)).identify(img, _circles(nodes))
    assert at3.tag == 42 and at3.hamming == 0 and at3.margin > 30
    assert np.abs(at3.corners - ours.corners).max() < 3.0


def test_margin_filter_rejects_weak_reads_and_tag_table_maps_ids():
    """An impossible margin rejects every read; a tag table maps the tag to its node."""
    nodes = layout(3, count=2)
    img = frame(nodes)
    strict = AprilTag3Identifier(AprilTag3Config(min_margin=1e6, fallback=False))
    assert strict.identify(img, _circles(nodes)) == [None, None]
    table = {nodes[0].tag: 900}
    reads = make_identifier(tag_table=table).identify(img, _circles(nodes))
    assert reads[0].node == 900 and reads[1].node is None


def test_unknown_family_is_refused():
    """An unknown family raises ValueError."""
    with pytest.raises(ValueError, match="unknown tag family"):
        make_identifier("tag99h1")


def test_family_the_library_lacks_falls_back_to_opencvs_reader():
    """tag36h10 (not in the AprilTag 3 binding) gets OpenCV's reader."""
    assert isinstance(make_identifier("tag36h10"), AprilTagIdentifier)


def test_many_readers_created_and_freed_do_not_crash():
    """Readers are freed safely (the binding's own destructor order reads freed memory)."""
    nodes = layout(0, count=2)
    img = frame(nodes)
    for _ in range(5):
        ident = AprilTag3Identifier()
        ident.identify(img, _circles(nodes))
        ident.close()
        del ident


class _CountingReader:
    """A fallback reader that records the circles it is asked about and reads nothing."""

    def __init__(self):
        self.asked = []

    def identify(self, image, circles):
        self.asked.extend(circles)
        return [None] * len(circles)


def test_fallback_mask_spares_the_fallback_reader():
    """identify(..., fallback=mask) hands only the flagged unread circles to the fallback reader."""
    nodes = [SceneNode(120, 120, 30, tag=None), SceneNode(320, 240, 30, tag=None)]
    spare = _CountingReader()
    ident = AprilTag3Identifier(fallback=spare)
    reads = ident.identify(frame(nodes), _circles(nodes), fallback=[False, True])
    assert reads == [None, None]
    assert [(c.u, c.v) for c in spare.asked] == [(320, 240)]
    with pytest.raises(ValueError):
        ident.identify(frame(nodes), _circles(nodes), fallback=[True])


def test_perception_skips_the_fallback_only_for_confidently_carried_circles():
    """Once a node's id is confident, frames whose tag the library cannot read skip the fallback; a new node's do not."""
    spare = _CountingReader()
    p = Perception("hough", identifier=AprilTag3Identifier(fallback=spare))  # (the drawn discs and nothing else)
    for k in range(5):  # the tag is read in 5 frames: the track's id is confident
        dets, _ = p.process(frame([SceneNode(200 + 2 * k, 200, 40, tag=11, tag_size=0.75)], seed=k))
        assert [d.node for d in dets] == [11]
    spare.asked.clear()
    for k in range(5, 8):  # tag gone: carried, the fallback is not asked; a second, unknown node is
        nodes = [SceneNode(200 + 2 * k, 200, 40, tag=None), SceneNode(450, 300, 40, tag=None)]
        dets, _ = p.process(frame(nodes, seed=k))
        assert dets[0].node == 11 if dets[0].circle.u < 300 else dets[1].node == 11
    assert spare.asked and all(c.u > 300 for c in spare.asked)
