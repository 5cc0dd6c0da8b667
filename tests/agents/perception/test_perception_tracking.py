"""The BoT-SORT-style tracker: ids through tag drop-outs, no swaps, empty frames, motion compensation."""

import numpy as np

from agents.perception import CircleTracker, Perception
from agents.perception.tracking import TrackerConfig
from agents.perception.kalman import circle_iou, warp_state
from agents.perception.types import Circle, TagRead
from perception_scenes import frame
from sims.lab.experiments.synthetic_scene import SceneNode


def _read(node):
    return TagRead(node, node, np.zeros((4, 2)), 0, 50.0, 1.0)


def test_id_kept_through_a_five_frame_tag_dropout():
    """On rendered frames, a node whose tag is unreadable for 5 frames keeps its id and track (hough: the tracker's
    test, on the detector that finds the one drawn disc and nothing else on this floor)."""
    p = Perception("hough")
    ids, tracks = [], []
    for k in range(14):
        tag = None if 5 <= k < 10 else 77
        img = frame([SceneNode(150 + 12 * k, 240 + 3 * k, 40, tag=tag, tag_size=0.75)], noise=2.0, seed=k)
        dets, _ = p.process(img)
        assert len(dets) == 1
        ids.append(dets[0].node)
        tracks.append(dets[0].track)
        if tag is None:
            assert dets[0].read is None
    assert ids == [77] * 14
    assert len(set(tracks)) == 1


def test_no_id_swap_when_two_nodes_cross():
    """Two nodes crossing (one passing in front of the other) keep their own ids on every frame."""
    p = Perception()
    for k in range(21):
        a = SceneNode(140 + 18 * k, 240, 36, tag=5 if k % 4 == 0 else None, tag_size=0.75)
        b = SceneNode(500 - 18 * k, 250, 30, tag=9 if k % 4 == 0 else None, tag_size=0.75)
        dets, _ = p.process(frame([a, b], noise=2.0, seed=k))
        for d in dets:
            if d.node is None:
                continue
            truth = a if d.node == 5 else b
            other = b if d.node == 5 else a
            assert np.hypot(d.circle.u - truth.u, d.circle.v - truth.v) < np.hypot(d.circle.u - other.u, d.circle.v - other.v)
        labelled = [d.node for d in dets if d.node is not None]
        assert len(labelled) == len(set(labelled))


def test_two_tracks_never_show_the_same_id():
    """Two detections both reading tag 3 in a frame: only one of them carries node 3."""
    t = CircleTracker()
    circles = [Circle(100, 100, 20, 0.9), Circle(300, 100, 20, 0.9)]
    for _ in range(3):
        out = t.update(circles, [_read(3), _read(3)])
        assert [o.node for o in out].count(3) == 1


def test_contradicting_read_does_not_flip_a_confident_id():
    """A track read as node 4 five times is not relabelled by a read of 8 and names node 4 again next frame."""
    t = CircleTracker()
    c = Circle(200, 200, 25, 0.9)
    first = t.update([c], [_read(4)])[0]
    for _ in range(4):
        t.update([c], [_read(4)])
    out = t.update([c], [_read(8)])
    assert out[0].track != first.track  # the contradicting detection may not join the confident track
    assert [tr.node for tr in t.tracks if tr.track_id == first.track] == [4]
    out = t.update([c], [None])
    assert out[0].node == 4 and out[0].track == first.track


def test_empty_frames_then_return():
    """After two empty frames a node re-appearing keeps its track and id."""
    t = CircleTracker()
    c = Circle(200, 200, 25, 0.9)
    first = t.update([c], [_read(6)])[0]
    for _ in range(2):
        assert t.update([], []) == []
    back = t.update([c], [None])[0]
    assert back.track == first.track and back.node == 6


def test_long_gap_needs_a_fresh_read():
    """After a long gap the re-found track names its node only once a tag read agrees again."""
    t = CircleTracker()
    c = Circle(200, 200, 25, 0.9)
    first = t.update([c], [_read(6)])[0]
    for _ in range(6):
        t.update([], [])
    back = t.update([c], [None])[0]
    assert back.track == first.track and back.node is None
    again = t.update([c], [_read(6)])[0]
    assert again.track == first.track and again.node == 6


def test_tagless_frames_leave_ids_unknown():
    """Without any tag read, detections are tracked but name no node."""
    t = CircleTracker()
    for k in range(3):
        out = t.update([Circle(100 + 5 * k, 100, 20, 0.9)], [None])
        assert out[0].node is None and out[0].track is not None


def test_camera_motion_compensation_keeps_a_fast_pan():
    """A 60 px pan per frame (more than a radius) is bridged when the homography is given."""
    t = CircleTracker()
    tracks = []
    for k in range(5):
        H = np.array([[1.0, 0, -60.0], [0, 1, 0], [0, 0, 1]])
        out = t.update([Circle(500 - 60 * k, 200, 20, 0.9)], [None], motion=H if k else None)
        tracks.append(out[0].track)
    assert len(set(tracks)) == 1


def test_warp_state_scales_radius_with_zoom():
    """A zoom homography moves the centre and scales the radius by its factor."""
    mean = np.array([100.0, 50.0, 10.0, 1.0, 0.0, 0.0])
    new, cov = warp_state(mean, np.eye(6), np.diag([2.0, 2.0, 1.0]))
    assert np.allclose(new[:4], [200.0, 100.0, 20.0, 2.0]) and cov.shape == (6, 6)


def test_circle_iou_basic_values():
    """IoU is 1 for identical discs, 0 for disjoint ones, and the area ratio for nested ones."""
    a = np.array([[0.0, 0.0, 2.0]])
    assert np.isclose(circle_iou(a, a)[0, 0], 1.0)
    assert circle_iou(a, np.array([[10.0, 0.0, 2.0]]))[0, 0] == 0.0
    assert np.isclose(circle_iou(a, np.array([[0.5, 0.0, 1.0]]))[0, 0], 0.25)


def _c(u, v, r, s=0.9):
    return Circle(u, v, r, s)


def test_sticker_outline_inside_a_node_starts_no_track():
    """A one-frame small circle inside a confirmed node's circle starts no track and shows no track number."""
    tr = CircleTracker()
    for k in range(3):
        tr.update([_c(200 + k, 200, 30)], [None])
    n_tracks = len(tr.tracks)
    out = tr.update([_c(203, 204, 12)], [None])  # the node missed, its sticker's outline seen
    assert out[0].track is None
    assert len(tr.tracks) == n_tracks
    out = tr.update([_c(204, 200, 30)], [None])
    assert out[0].track == 1


def test_unconfirmed_track_shows_no_number():
    """A new track (after the first frame) shows its number only once confirmed by a second hit."""
    tr = CircleTracker()
    tr.update([_c(100, 100, 20)], [None])
    first = tr.update([_c(100, 100, 20), _c(400, 300, 20)], [None, None])
    assert first[0].track == 1 and first[1].track is None
    second = tr.update([_c(100, 100, 20), _c(401, 300, 20)], [None, None])
    assert second[1].track is not None


def _known(tr, circles, reads, frames=4):
    """Run ``tr`` over the same detections and reads for ``frames`` frames (the ids confirmed); the last outputs."""
    for _ in range(frames):
        out = tr.update(circles, reads)
    return out


def _id_hidden_until_a_read_agrees(tr, circle, node):
    """The low-overlap match ``circle`` keeps track 1 but hides its id; a read of ``node`` shows it again."""
    out = tr.update([circle], [None])
    assert out[0].track == 1 and out[0].node is None
    assert tr.update([circle], [_read(node)])[0].node == node


def test_track_jumping_to_a_neighbour_needs_a_fresh_read():
    """A track that reaches a barely overlapping detection (a neighbouring node) hides its id until a read agrees."""
    tr = CircleTracker()
    assert _known(tr, [_c(200, 200, 20)], [_read(7)])[0].node == 7
    _id_hidden_until_a_read_agrees(tr, _c(226, 200, 20), 7)  # within the enlarged radii, IoU of the plain circles < 0.4


def test_contested_jump_needs_a_fresh_read_even_when_trusting_uncontested_ones():
    """With trust_uncontested, a low-overlap match that another track also reaches still hides the id until a read agrees."""
    tr = CircleTracker(TrackerConfig(trust_uncontested=True))
    # node 7, and a neighbour below it whose tag is never read
    assert _known(tr, [_c(200, 200, 20), _c(226, 236, 20)], [_read(7), None])[0].node == 7
    # node 7 is missed; the only detection lies between its track and the neighbour's: both gates hold it
    _id_hidden_until_a_read_agrees(tr, _c(226, 204, 20), 7)  # within the enlarged radii, IoU of the plain circles < 0.4


def test_uncontested_fast_move_keeps_the_id():
    """With trust_uncontested, a lone node that suddenly moves further than predicted (IoU < 0.4, no rival) keeps its id."""
    tr = CircleTracker(TrackerConfig(trust_uncontested=True))
    _known(tr, [_c(200, 200, 20)], [_read(7)])
    out = tr.update([_c(226, 200, 20)], [None])  # the same jump as a neighbour's, but nothing competes
    assert out[0].track == 1 and out[0].node == 7


def test_a_much_larger_circle_on_a_track_needs_a_fresh_read_even_when_uncontested():
    """A nearer node sliding in front of a hidden one is found where the hidden one's track is: nothing
    contests it, but its radius is a third larger than the track's, so the track hides its id until a read
    agrees (on held-out scene 1002 such a track carried a hidden node's id for 12 frames); a few per cent
    of growth a frame (a node coming closer) keeps it."""
    tr = CircleTracker(TrackerConfig(trust_uncontested=True))
    _known(tr, [_c(200, 200, 30)], [_read(7)])
    _id_hidden_until_a_read_agrees(tr, _c(206, 208, 42), 7)
    tr = CircleTracker(TrackerConfig(trust_uncontested=True))
    _known(tr, [_c(200, 200, 30)], [_read(7)])
    assert [tr.update([_c(200, 200, 30 * 1.05 ** k)], [None])[0].node for k in range(1, 6)] == [7] * 5


def test_perception_trusts_uncontested_jumps_only_with_a_detector_that_finds_neighbours():
    """Perception's default tracker keeps ids through uncontested jumps for the learned detector, not for hough."""
    assert Perception("learned").tracker.config.trust_uncontested
    assert not Perception("hough").tracker.config.trust_uncontested


def _feed(tracker, circles, node_of):
    """One frame as the pipeline runs it: settled circles are not read, the others read ``node_of(j)``."""
    skip = tracker.settled(circles)
    reads = [None if s else (_read(node_of(j)) if node_of(j) is not None else None) for j, s in enumerate(skip)]
    return skip, tracker.update(circles, reads)


def test_settled_track_is_reread_every_nth_frame():
    """A confidently identified, unambiguous track skips reads, but never more than reread_every - 1 frames in a row."""
    t = CircleTracker(TrackerConfig(settle_votes=4, reread_every=3))
    skipped, gap, longest = 0, 0, 0
    for k in range(30):
        skip, out = _feed(t, [Circle(200 + 2 * k, 150, 25, 0.9)], lambda j: 4)
        assert out[0].node == 4
        skipped += int(skip[0])
        gap = gap + 1 if skip[0] else 0
        longest = max(longest, gap)
    assert skipped >= 10
    assert longest == 2


def test_no_read_is_skipped_before_enough_votes():
    """A track with fewer than settle_votes reads of its id is read in every frame."""
    t = CircleTracker(TrackerConfig(settle_votes=4, reread_every=3))
    skips = [bool(_feed(t, [Circle(200, 150, 25, 0.9)], lambda j: 4)[0][0]) for _ in range(4)]
    assert skips == [False] * 4


def test_reread_every_one_reads_every_circle():
    """reread_every = 1 switches skipping off."""
    t = CircleTracker(TrackerConfig(reread_every=1))
    assert not any(bool(_feed(t, [Circle(200, 150, 25, 0.9)], lambda j: 4)[0][0]) for _ in range(12))


def test_ambiguous_circles_are_always_read():
    """Two circles overlapping one settled track are both read (a neighbour may have moved in)."""
    t = CircleTracker(TrackerConfig(settle_votes=4, reread_every=3))
    for _ in range(6):
        _feed(t, [Circle(200, 150, 25, 0.9)], lambda j: 4)
    skip = t.settled([Circle(200, 150, 25, 0.9), Circle(220, 150, 25, 0.9)])
    assert not skip.any()


def test_pipeline_reads_fewer_circles_with_the_same_ids():
    """Perception skips reads of settled tracks: fewer circles read, the same node ids shown."""

    class Counting:
        def __init__(self, inner):
            self.inner, self.read = inner, 0

        def identify(self, image, circles):
            self.read += len(circles)
            return self.inner.identify(image, circles)

    from agents.perception import AprilTagIdentifier

    runs = {}
    for every in (1, 3):
        ident = Counting(AprilTagIdentifier())
        p = Perception(identifier=ident, tracker=CircleTracker(TrackerConfig(reread_every=every)))
        nodes = []
        for k in range(14):
            img = frame([SceneNode(150 + 8 * k, 240, 40, tag=77, tag_size=0.75),
                         SceneNode(480, 300 - 4 * k, 36, tag=12, tag_size=0.75)], noise=2.0, seed=k)
            dets, _ = p.process(img)
            nodes.append(sorted(d.node for d in dets if d.node is not None))
        runs[every] = (ident.read, nodes)
    assert runs[3][0] < runs[1][0] * 0.75
    assert runs[3][1] == runs[1][1]
    assert runs[3][1][-1] == [12, 77]


def test_carried_marks_only_lone_confident_tracks():
    """carried() is True for a circle on a lone track with a confident id, False beside a rival or before confidence."""
    tr = CircleTracker()
    for k in range(2):
        tr.update([_c(200, 200, 20), _c(400, 200, 20)], [_read(7), None])
    assert not tr.carried([_c(200, 200, 20)]).any()  # 2 reads: not confident yet
    tr.update([_c(200, 200, 20), _c(400, 200, 20)], [_read(7), None])
    assert tr.carried([_c(200, 200, 20), _c(400, 200, 20)]).tolist() == [True, False]
    assert tr.carried([_c(200, 200, 20), _c(215, 200, 20)]).tolist() == [False, False]  # a rival touches it
    tr.update([_c(200, 200, 20), _c(400, 200, 20)], [None, None])  # carried() changed nothing
    assert [t.votes for t in tr.tracks] == [{7: 3}, {}]
