"""The pose gossip table: newest rows win, own row stays own, the table goes out only when it changed or is due."""

import numpy as np

from decentral.geometry import rot2
from protocols.pose_gossip import PoseGossip, pose_row

EPS = 1e-4


def _row(i, step, round_index, x=0.0, theta=0.0):
    return pose_row(i, step, round_index, rot2(theta), np.array([x, 0.0, 0.0]))


def _gossip(me=0, n=3, refresh=10):
    return PoseGossip(me, n, EPS, refresh)


def test_pose_row_holds_index_step_round_position_and_yaw():
    """A row is (index, step, round, x, y, z, theta) with theta the yaw of R."""
    row = pose_row(2, 7, 11, rot2(0.3), np.array([1.0, 2.0, 3.0]))
    assert np.allclose(row, [2, 7, 11, 1.0, 2.0, 3.0, 0.3])


def test_a_late_or_reordered_row_never_overwrites_a_newer_one():
    """A row older by (step, round) than the held one is dropped; a newer one replaces it."""
    g = _gossip()
    g.merge(np.array([_row(1, 4, 20, x=1.0)]), round_index=20)
    g.merge(np.array([_row(1, 4, 19, x=9.0), _row(1, 3, 30, x=9.0)]), round_index=21)
    assert g.rows[1][3] == 1.0
    g.merge(np.array([_row(1, 5, 2, x=2.0)]), round_index=22)
    assert g.rows[1][3] == 2.0 and g.rows[1][1] == 5


def test_the_holders_own_row_and_foreign_indices_are_not_taken_from_others():
    """Rows naming the holder itself or an index outside 0..n-1 are ignored by merge."""
    g = _gossip(me=0, n=2)
    g.merge(np.array([_row(0, 9, 9, x=5.0), _row(2, 9, 9), _row(-1, 9, 9)]), round_index=9)
    assert not g and g.version == 0


def test_a_duplicate_copy_is_not_a_change():
    """Merging the same table twice bumps the version once and leaves `changed` at the first round."""
    g = _gossip()
    table = np.array([_row(1, 2, 5), _row(2, 2, 5)])
    g.merge(table, round_index=5)
    version = g.version
    g.merge(table, round_index=8)
    assert g.version == version and g.changed == 5 and g.settled(7) and not g.settled(6)


def test_a_move_within_eps_is_not_material_but_a_new_step_is():
    """Own row: a pose moved by <= eps keeps the version; a move > eps or a new step bumps it."""
    g = _gossip()
    g.set_own(_row(0, 3, 1), round_index=1)
    v = g.version
    g.set_own(_row(0, 3, 2, x=EPS / 2), round_index=2)
    assert g.version == v and g.changed == 1 and g.rows[0][3] == EPS / 2  # written, not announced
    g.set_own(_row(0, 3, 3, x=3 * EPS), round_index=3)
    assert g.version == v + 1
    g.set_own(_row(0, 4, 4, x=3 * EPS), round_index=4)
    assert g.version == v + 2 and g.changed == 4


def test_fill_writes_every_row_and_always_counts_as_a_change():
    """A joint solution's rows are written at once (own row too) and mark the table changed."""
    g = _gossip(me=0)
    g.fill([_row(0, 6, 3), _row(2, 6, 3, x=1.0)], round_index=3)
    assert sorted(g.rows) == [0, 2] and g.version == 1 and g.changed == 3


def test_the_table_goes_out_when_changed_and_again_after_refresh_rounds_to_repair_a_loss():
    """Send half: nothing while empty; then once per receiver per version, and again `refresh` rounds later."""
    g = _gossip(refresh=4)
    assert g.attach("A1", 0) is None
    g.fill([_row(0, 0, 0), _row(1, 0, 0)], round_index=0)
    sent = g.attach("A1", 1)
    assert sent.shape == (2, 7) and list(sent[:, 0]) == [0, 1]  # sorted by assembly index
    assert g.attach("A1", 2) is None and g.attach("A2", 2) is not None  # per receiver
    assert g.attach("A1", 4) is None and g.attach("A1", 5) is not None  # the copy at round 1 may be lost
    g.set_own(_row(0, 1, 6), round_index=6)
    assert g.attach("A1", 6) is not None  # a material change goes out at once


def test_two_tables_converge_to_the_newest_rows_whatever_the_delivery_order():
    """Merging the same copies in any order ends with the same rows (newest by (step, round))."""
    copies = [np.array([_row(1, s, r, x=s + r / 100)]) for s, r in [(1, 3), (2, 1), (2, 5), (1, 9)]]
    results = []
    for order in ([0, 1, 2, 3], [3, 2, 1, 0], [2, 0, 3, 1]):
        g = _gossip()
        for k in order:
            g.merge(copies[k], round_index=k)
        results.append(g.rows[1].copy())
    assert all(np.array_equal(r, results[0]) for r in results) and results[0][1] == 2 and results[0][2] == 5
