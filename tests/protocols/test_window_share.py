"""One window's shared forms as typed state (protocols.window_share): the joint solution and what it places."""

import numpy as np

from decentral.admm import LocalProblem, quadratic_form
from protocols.aggregation import TreeAggregation
from protocols.window_share import WindowShare

Q = np.array([[0.1, 0.0, 0.0], [0.0, 0.1, 0.05], [-0.1, 0.05, 0.0]])


def _share(step=0, pin=None, forms=True) -> WindowShare:
    """A0 (reference) and A1 1 m ahead of it, A1's pair form of ``step`` held."""
    agg = TreeAggregation(0, 2, root=True, parent=None)
    prob = quadratic_form([("A1", step), ("A0", step)], visual=(
        np.zeros(3, int), np.ones(3, int), Q, Q + np.array([1.0, 0, 0]), np.ones(3)))
    agg.add({0: [], 1: [(((1, step), (0, step)), prob)] if forms else []})
    return WindowShare(step=step, agg=agg, pin=pin)


def test_the_joint_solution_is_computed_once_and_places_the_observed_assembly():
    """solve() finds A0 1 m ahead of A1; the placement test places A0 relative to A1; the result is kept."""
    share = _share()
    assert not share.solved and share.solve("A0", 0) and share.solved
    R, p = share.joint.poses[("A1", 0)]
    assert np.allclose(p, [-1.0, 0.0, 0.0], atol=1e-9) and np.allclose(R, np.eye(2), atol=1e-9)
    keys = share.placeable_keys(share.joint, "A1", 0, np.inf)
    assert ("A0", 0) in keys and share.placeable_keys(None, "A1", 0, np.inf) is keys
    assert share.unplaced(share.joint, ("A0", "A1"), "A1", 0, np.inf) == {}


def test_no_joint_solution_without_the_gauge_of_the_window_or_without_forms():
    """A window after step 0 is solved only with the reference's pin of its first step (A0 there); no forms, no solution."""
    later = _share(step=6)
    assert later.solve("A0", 2) and later.joint is None
    pinned = _share(step=2, pin=np.array([2, 0.5, 0.2, 0.0, 0.0]))
    assert pinned.solve("A0", 2)
    assert np.allclose(pinned.joint.poses[("A0", 2)][1], [0.5, 0.2, 0.0]) and np.allclose(
        pinned.joint.poses[("A1", 2)][1], [-0.5, 0.2, 0.0], atol=1e-9)  # the gauge at the reference's pin
    empty = _share(forms=False)
    assert empty.solve("A0", 0) and empty.joint is None


def test_records_edges_and_observers_come_from_the_pair_forms():
    """The view graph's edges and an agent's observers are read off the pair forms' keys (observer first)."""
    share = _share()
    assert share.edges() == {(1, 0)} and share.observers_of(0) == {1} and share.observers_of(1) == set()
    assert all(isinstance(p, LocalProblem) for p in share.problems())


def test_a_bundle_carries_the_gauge_pin_only_with_the_references_record():
    """The pin rides with the reference's record; a bundle without it carries none."""
    share = _share(step=2, pin=np.array([2, 0.5, 0.2, 0.0, 0.0]))
    with_ref = share.bundle("A1", "A0", [0, 1], down=False, start=0, round_index=7, reference=0)
    without = share.bundle("A1", "A0", [1], down=False, start=0, round_index=7, reference=0)
    assert np.array_equal(with_ref.pin, share.pin) and len(without.pin) == 0
    assert with_ref.members.tolist() == [0, 1] and without.members.tolist() == [1] and with_ref.step == 2
    assert share.ack("A0", "A1", 8).have.tolist() == [0, 1]


def test_the_solution_message_holds_the_newest_poses_and_the_graph_only_when_given():
    """The joint solution goes down as the newest step's poses of every agent; the edge mask only when given."""
    share = _share()
    share.solve("A0", 0)
    index = {"A0": 0, "A1": 1}
    sent = share.solution_message("A0", share.joint, index, {0, 1}, {(1, 0)}, 9, 2)
    assert sent.indices("members") == [0, 1] and sent.indices("placeable") == [0, 1]
    assert np.allclose(sent.pose_of()[1][0], [-1.0, 0.0, 0.0], atol=1e-6) and sent.edge_set() == {(1, 0)}
    assert len(share.solution_message("A0", share.joint, index, {0, 1}, None, 9, 2).edges) == 0


def test_a_window_solved_again_without_a_member_leaves_out_its_forms_and_places_afresh():
    """without(["A2"]): a copy solved from the forms over no pose of A2 (A1 still 1 m behind A0, A2 gone and
    unplaced); the window itself keeps its solution and placement; nothing left, or no gauge value: None."""
    agg = TreeAggregation(0, 3, root=True, parent=None)
    a1 = quadratic_form([("A1", 0), ("A0", 0)], visual=(np.zeros(3, int), np.ones(3, int), Q, Q + [1.0, 0, 0], np.ones(3)))
    a2 = quadratic_form([("A2", 0), ("A0", 0)], visual=(np.zeros(3, int), np.ones(3, int), Q, Q + [2.0, 0, 0], np.ones(3)))
    agg.add({0: [], 1: [(((1, 0), (0, 0)), a1)], 2: [(((2, 0), (0, 0)), a2)]})
    share = WindowShare(step=0, agg=agg)
    assert share.solve("A0", 0)
    placed = share.placeable_keys(share.joint, "A0", 0, np.inf)
    assert ("A2", 0) in placed
    again = share.without({"A2"}, "A0", 0)
    assert again is not None and again.excluded == ("A2",) and again is not share
    assert set(again.joint.poses) == {("A0", 0), ("A1", 0)}
    assert np.allclose(again.joint.poses[("A1", 0)][1], [-1.0, 0.0, 0.0], atol=1e-9)
    assert ("A2", 0) not in again.placeable_keys(again.joint, "A0", 0, np.inf)
    assert "A2" in again.unplaced(again.joint, ("A0", "A1", "A2"), "A0", 0, np.inf)
    assert share.excluded == () and ("A2", 0) in share.joint.poses and share.placeable_keys(None, "A0", 0, np.inf) is placed
    assert share.without({"A1", "A2"}, "A0", 0) is None  # (the gauge alone: nothing to solve)
    assert _share(step=2).without({"A2"}, "A0", 2) is None  # (no gauge value at this window here)
