"""One agent's sharing of a window's cost forms (protocols.window_aggregation), driven by hand-built messages.

Three agents on a chain: A0 (the reference, root) <- A1 <- A2, each observing the one before it at
step 0 (A1 sits 1 m from A0 along x, A2 2 m), so the joint solution is known exactly.
"""

import numpy as np
import pytest

from decentral.admm import quadratic_form
from protocols.admm_messages import FactorShare, FormAck, FormBundle, pack_bundle, pack_forms
from protocols.delta_messages import DeltaBundle, FactorDelta, JointPoses
from protocols.messages import BROADCAST
from protocols.window_aggregation import WindowAggregation

NAMES = ("A0", "A1", "A2")
Q = np.array([[0.1, 0.0, 0.0], [0.0, 0.1, 0.05], [-0.1, 0.05, 0.0]])  # target's nodes in its own frame


def _form(observer: int, target: int, step: int = 0) -> tuple:
    """The packed pair form ``(keys, M, b_z, c_z, count)`` of ``observer`` seeing ``target`` 1 m ahead (no rotation)."""
    offset = np.array([observer - target, 0.0, 0.0])
    keys = [(NAMES[observer], step), (NAMES[target], step)]
    prob = quadratic_form(keys, visual=(np.zeros(3, int), np.ones(3, int), Q, Q - offset, np.ones(3)))
    return ((observer, step), (target, step)), prob.M, prob.b_z, prob.c_z, prob.count


def _records(*members) -> dict:
    """Agent index -> its packed forms (agent i > 0 observes agent i - 1; A0 has no form)."""
    return {i: ([_form(i, i - 1)] if i > 0 else []) for i in members}


def _bundle(sender, receiver, members, *, down, hop, parent, depth, start=0, step=0) -> FormBundle:
    m, owners, keys, forms = pack_bundle(_records(*members))
    return FormBundle(sender=sender, receiver=receiver, round=0, step=step, down=down, hop=hop, parent=parent,
                      depth=depth, start=start, members=m, owners=owners, keys=keys, forms=forms, pin=np.zeros(0))


def _role(name: str, round_index: int = 10, share_timeout: int = 24, aggregation: str = "tree"):
    out = []
    counters = {k: 0 for k in ("ignored", "retransmits", "late_seeds", "tree_windows", "broadcast_windows",
                               "joint_failures", "unrebuilt")}
    role = WindowAggregation(name, NAMES, "A0", aggregation=aggregation, window=5, share_timeout=share_timeout,
                             placement_limit=np.inf, counters=counters, send=out.append)
    role.round = round_index
    return role, out


def _open(role, parent, hop, own):
    """Open window 0 below ``parent`` and share the agent's own forms."""
    role.open(0, parent, hop, wait=6)
    role.step = 0
    role.share_own(_records(own)[own], np.zeros(0))


def _middle(**kw):
    """A1 with A2 as its child (heard naming A1 its parent) and its own forms shared."""
    role, out = _role("A1", **kw)
    role.tree.heard("A2", 2, 1, role.round, None)
    _open(role, parent=0, hop=1, own=1)
    return role, out


def _finished_middle(start):
    """A1 after its child's bundle up and the down bundle (ADMM from round ``start``): the window finished."""
    role, out = _middle()
    role.on_bundle(_bundle("A2", "A1", [2], down=False, hop=2, parent=1, depth=2))
    role.on_bundle(_bundle("A0", "A1", [0, 1, 2], down=True, hop=0, parent=-1, depth=2, start=start))
    role.progress(parent=0)
    role.finish()
    out.clear()
    return role, out


def test_the_bundle_up_waits_for_the_child_and_carries_its_record():
    """A middle agent sends nothing up until its child reports, then one delta to its parent with both records."""
    role, out = _middle()
    assert not role.progress(parent=0) and out == []
    role.on_bundle(_bundle("A2", "A1", [2], down=False, hop=2, parent=1, depth=2))
    ack = [m for m in out if isinstance(m, FormAck)]
    up = [m for m in out if isinstance(m, DeltaBundle)]
    assert len(ack) == 1 and ack[0].receiver == "A2" and ack[0].have.tolist() == [1, 2]
    assert len(up) == 1 and up[0].receiver == "A0" and up[0].members.tolist() == [1, 2]


def test_an_unacknowledged_bundle_up_is_resent_whole():
    """Without the parent's acknowledgement, the records go up again after 3 rounds carrying every form (a delta
    with nothing left to rebuild), and a parent holding another version of a form takes the record as it came."""
    role, out = _role("A1")
    _open(role, parent=0, hop=1, own=1)
    role.progress(parent=0)
    assert [type(m) for m in out] == [DeltaBundle]
    role.round += 3
    role.progress(parent=0)
    resent = out[-1]
    assert isinstance(resent, DeltaBundle) and resent.receiver == "A0" and role.counters["retransmits"] == 1
    assert len(resent.owners) == resent.digest[0, 0] == 1  # (every form of A1's record, not only the new ones)
    parent, _ = _role("A0")
    _open(parent, parent=None, hop=0, own=0)
    stale = _form(1, 0)
    parent.forms.remember(1, parent.messages.problems([(((1, 0), (0, 0)), 2 * stale[1], stale[2], stale[3], stale[4])]))
    parent.forms.remember(1, parent.messages.problems([(((1, -1), (1, 0)), stale[1], stale[2], stale[3], stale[4])]))
    parent.on_delta(resent)
    assert parent.share.agg.complete is False and 1 in parent.share.agg.records
    np.testing.assert_array_equal(parent.share.agg.records[1][0][1].M, _form(1, 0)[1].astype(np.float32))


def test_the_root_sends_the_joint_solution_down_once_complete():
    """The root holding every record sends its child the joint solution (A1 at x = 1 m) and a common start round."""
    role, out = _role("A0")
    role.tree.heard("A1", 1, 0, role.round, None)
    _open(role, parent=None, hop=0, own=0)
    role.on_bundle(_bundle("A1", "A0", [1, 2], down=False, hop=1, parent=0, depth=2))
    down = [m for m in out if isinstance(m, JointPoses)]
    assert len(down) == 1 and down[0].receiver == "A1" and down[0].start == role.round + 2 // 2 + 2
    poses = down[0].pose_of()
    assert np.allclose(poses[1][0], [1.0, 0.0, 0.0], atol=1e-5) and np.allclose(poses[2][0], [2.0, 0.0, 0.0], atol=1e-5)
    assert role.progress(parent=None)
    share, partial = role.finish()
    assert not partial and share.agg.complete and role.share is None


def test_a_down_bundle_is_forwarded_to_the_children_and_acknowledged():
    """The final set from the parent goes on to the child at once and is acknowledged; the window then finishes."""
    role, out = _middle()
    role.on_bundle(_bundle("A2", "A1", [2], down=False, hop=2, parent=1, depth=2))
    out.clear()
    role.on_bundle(_bundle("A0", "A1", [0, 1, 2], down=True, hop=0, parent=-1, depth=2, start=15))
    forwarded = [m for m in out if isinstance(m, FormBundle)]
    assert len(forwarded) == 1 and forwarded[0].receiver == "A2" and forwarded[0].down and forwarded[0].start == 15
    assert any(isinstance(m, FormAck) and m.receiver == "A0" for m in out)
    assert role.progress(parent=0)
    share, partial = role.finish()
    assert share.start_at == 15 and not partial


def test_a_solution_coming_down_finishes_the_window_and_is_forwarded():
    """A JointPoses from the parent ends the sharing at once (on_solution says so) and reaches the child."""
    role, out = _middle()
    role.on_bundle(_bundle("A2", "A1", [2], down=False, hop=2, parent=1, depth=2))
    out.clear()
    n = len(NAMES)
    solution = JointPoses(sender="A0", receiver="A1", round=0, step=0, hop=0, parent=-1, depth=2, start=14, n=n,
                          members=JointPoses.mask([0, 1, 2], n), index=JointPoses.mask([0, 1, 2], n),
                          poses=np.array([[0, 0, 0, 0], [1, 0, 0, 0], [2, 0, 0, 0]], float),
                          placeable=JointPoses.mask([0, 1, 2], n), edges=np.zeros(0, np.uint8))
    assert role.on_solution(solution)
    assert [m.receiver for m in out if isinstance(m, JointPoses)] == ["A2"]
    share, partial = role.finish()
    assert share.solution is solution and not partial


def test_a_timed_out_window_stays_open_and_a_late_complete_set_reopens_it():
    """A silent parent: the window finishes partial at 2 * share_timeout + hop rounds (the parent is dropped
    from the tree), and a complete down bundle arriving later makes it finish again, complete (a late seed)."""
    role, out = _role("A1", share_timeout=4)
    _open(role, parent=0, hop=1, own=1)
    role.tree.heard("A0", 0, -1, role.round, 0)
    finished, rounds = False, 0
    while not finished:
        finished = role.progress(parent=0)
        role.round += 1
        rounds += 1
    assert rounds == 2 * 4 + 1 + 1 and "A0" not in role.tree.entries
    share, partial = role.finish()
    assert partial and role.late is not None and not share.agg.complete
    assert role.on_bundle(_bundle("A0", "A1", [0, 1, 2], down=True, hop=0, parent=-1, depth=1))
    assert role.counters["late_seeds"] == 1
    share, partial = role.finish()
    assert share.agg.complete and not partial and role.late is None


def test_after_a_timeout_the_parent_is_asked_for_the_down_bundle_every_three_rounds():
    """A window left partial asks its parent again (its records up) every 3 rounds, at most 10 times."""
    role, out = _role("A1", share_timeout=2)
    _open(role, parent=0, hop=1, own=1)
    while not role.progress(parent=0):
        role.round += 1
    role.finish()
    out.clear()
    asks = 0
    for _ in range(60):
        role.round += 1
        before = len(out)
        role.ask_down()
        asks += len(out) - before
    assert asks == 10 and all(isinstance(m, FormBundle) and m.receiver == "A0" and not m.down for m in out)


def test_a_bundle_from_below_after_the_window_finished_gets_the_down_bundle_again():
    """A child whose bundle arrives once the window has finished (it lacks the down bundle) gets it directly."""
    role, out = _finished_middle(start=15)
    role.on_bundle(_bundle("A2", "A1", [2], down=False, hop=2, parent=1, depth=2))
    assert len(out) == 1 and isinstance(out[0], FormBundle) and out[0].down and out[0].receiver == "A2"
    assert out[0].members.tolist() == [0, 1, 2]


def test_a_lost_down_bundle_is_resent_to_a_child_not_heard_from():
    """repair_down resends the down bundle to a silent child from start + 2 rounds, never to one heard from."""
    role, out = _finished_middle(start=12)
    role.round = 13
    role.repair_down(lambda name: False)
    assert out == []
    role.round = 14
    role.repair_down(lambda name: False)
    assert [(type(m), m.receiver, m.down) for m in out] == [(FormBundle, "A2", True)]
    role.round = 17
    role.repair_down(lambda name: name == "A2")
    assert len(out) == 1 and not role.down.repair


def test_a_share_lacking_this_agent_is_answered_directly_and_only_broadcasts_are():
    """A broadcast share whose `have` lacks this agent gets its forms by unicast; a unicast share gets nothing."""
    role, out = _role("A1", aggregation="broadcast")
    _open(role, parent=None, hop=None, own=1)
    keys, forms = pack_forms(_records(2)[2])
    share = FactorShare(sender="A2", receiver=BROADCAST, round=0, step=0, have=np.array([2]), keys=keys, forms=forms,
                        pin=np.zeros(0))
    role.on_factors(share)
    assert [(type(m), m.receiver) for m in out] == [(FactorShare, "A2")]
    assert out[0].have.tolist() == [1, 2]
    out.clear()
    role.on_factors(FactorShare(sender="A2", receiver="A1", round=0, step=0, have=np.array([2]), keys=keys,
                                forms=forms, pin=np.zeros(0)))
    assert out == []


def test_a_broadcast_from_the_parent_turns_the_window_to_broadcasting():
    """A tree agent whose parent broadcasts its forms (it has no route) broadcasts its own too."""
    role, out = _role("A1")
    _open(role, parent=0, hop=1, own=1)
    assert role.share.mode == "tree"
    keys, forms = pack_forms([])
    role.on_factors(FactorShare(sender="A0", receiver=BROADCAST, round=0, step=0, have=np.array([0]), keys=keys,
                                forms=forms, pin=np.zeros(0)))
    assert role.share.mode == "broadcast"
    role.progress(parent=0)
    assert any(isinstance(m, (FactorShare, FactorDelta)) and m.receiver == BROADCAST for m in out)


@pytest.mark.parametrize("bad", ["keys", "members"])
def test_indices_beyond_the_agents_are_counted_and_ignored(bad):
    """A bundle naming an agent index that does not exist changes nothing and counts as ignored."""
    role, out = _middle()
    records = {5 if bad == "members" else 2: [(((2, 0), (7 if bad == "keys" else 1, 0)), *_form(2, 1)[1:])]}
    m, owners, keys, forms = pack_bundle(records)
    role.on_bundle(FormBundle(sender="A2", receiver="A1", round=0, step=0, down=False, hop=2, parent=1, depth=2,
                              start=0, members=m, owners=owners, keys=keys, forms=forms, pin=np.zeros(0)))
    assert role.counters["ignored"] == 1 and out == [] and sorted(role.share.records) == [1]


def test_agents_not_heard_from_for_two_windows_are_not_waited_for():
    """After two windows listened through, a window is complete without the records of agents not heard in the
    last two; windows the agent did not listen through (off the CPU) do not count."""
    role, _ = _role("A1")
    assert role.alive_members() is None
    role.heard(2)
    role.liveness.listened = 1
    role.heard(0), role.heard(1)
    role.liveness.listened = 3
    assert role.alive_members() == {0, 1}
    role.heard(2)
    assert role.alive_members() == {0, 1, 2}


def test_an_agent_given_up_on_and_heard_again_is_waited_for():
    """A window opened without A2 (not heard for two windows) waits for A2's record once A2 is heard again."""
    role, _ = _role("A0")
    role.heard(2)
    role.liveness.listened = 3
    role.heard(1)
    role.open(4, None, 0, wait=6)
    role.step = 4
    role.share.agg.add(_records(0, 1))
    assert role.share.agg.complete  # (A2 given up on)
    role.heard(2)
    assert not role.share.agg.complete


def test_records_a_partial_down_bundle_lacked_are_resent_until_acknowledged():
    """A1's record missing from the root's down bundle goes up again every `resend_after` rounds, every form
    carried, until the root acknowledges it; then nothing more is sent."""
    role, out = _middle()
    role.on_bundle(_bundle("A2", "A1", [2], down=False, hop=2, parent=1, depth=2))
    out.clear()
    role.on_bundle(_bundle("A0", "A1", [0, 2], down=True, hop=0, parent=-1, depth=2))  # (timed out without A1's)
    sent = [m for m in out if isinstance(m, DeltaBundle)]
    assert len(sent) == 1 and sent[0].members.tolist() == [1] and len(sent[0].owners) == 1
    role.round += role.resend_after
    role.resend_owed()
    assert len([m for m in out if isinstance(m, DeltaBundle)]) == 2
    role.on_ack(FormAck(sender="A0", receiver="A1", round=0, step=0, have=np.array([0, 1, 2])))
    out.clear()
    role.round += 10 * role.resend_after
    role.resend_owed()
    assert out == [] and role.owed is None


def _broadcast_window(role, step: int, own: int) -> None:
    """Open window ``step`` of a broadcasting ``role``, share its own forms of steps 0..step (agent ``own``
    observes ``own - 1`` at every step) and run its first bootstrap phase (it broadcasts them)."""
    role.open(step, None, None, wait=6)
    role.step = step
    role.share_own([_form(own, own - 1, k) for k in range(step + 1)], np.zeros(0))
    role.progress(parent=None)


def _broadcasts(role, out: list, steps: int) -> list:
    """What A2 (``role``, sending into ``out``) broadcasts in its windows 0 .. ``steps - 1``."""
    sent = []
    for step in range(steps):
        out.clear()
        _broadcast_window(role, step, own=2)
        sent.append(next(m for m in out if m.receiver == BROADCAST))
    return sent


def _steps_carried(message: FactorDelta) -> list[int]:
    return sorted({k[0][1] for k, *_ in message.carried()})


def test_a_broadcast_window_carries_only_the_forms_of_its_last_two_steps_and_a_digest_of_the_rest():
    """Windows 0, 1, 2 by broadcast: the first carries every form, later ones only those of their last two steps
    (each step's forms are the same from window to window), and the digest always counts the whole record."""
    sent = _broadcasts(*_role("A2", aggregation="broadcast"), steps=3)
    assert all(isinstance(m, FactorDelta) for m in sent)
    assert [_steps_carried(m) for m in sent] == [[0], [0, 1], [1, 2]]
    assert [int(m.digest[0]) for m in sent] == [1, 2, 3]


def test_a_receiver_rebuilds_a_compact_broadcast_from_the_forms_it_holds_or_asks_for_every_form():
    """A1 that heard A2's earlier broadcasts takes A2's window-2 record from a broadcast carrying steps 1-2 only
    (equal to A2's whole record); a fresh A1 cannot, leaves A2 out of its `have`, and A2 answers it with every
    form, which it takes."""
    sender, sent = _role("A2", aggregation="broadcast")
    broadcasts = _broadcasts(sender, sent, steps=3)

    heard, _ = _role("A1", aggregation="broadcast")
    for step, message in enumerate(broadcasts):
        heard.open(step, None, None, wait=6)
        heard.step = step
        heard.on_factor_delta(message)
        assert 2 in heard.share.records
    whole = sorted(k for k, _ in heard.share.records[2])
    assert whole == [((2, k), (1, k)) for k in range(3)]

    fresh, out = _role("A1", aggregation="broadcast")
    _broadcast_window(fresh, 2, own=1)
    fresh.on_factor_delta(broadcasts[2])
    assert 2 not in fresh.share.records and fresh.counters["unrebuilt"] == 1
    mine = next(m for m in out if m.receiver == BROADCAST)
    assert 2 not in mine.have.tolist()
    sent.clear()
    sender.on_factor_delta(mine)  # A1's broadcast lacks A2's forms: answered with all of them
    answer, = [m for m in sent if m.receiver == "A1"]
    assert isinstance(answer, FactorDelta) and _steps_carried(answer) == [0, 1, 2]
    fresh.on_factor_delta(answer)
    assert sorted(k for k, _ in fresh.share.records[2]) == whole


def test_forms_of_a_compact_broadcast_far_from_the_window_are_not_kept():
    """A peer's compact broadcast of a window that does not overlap this agent's (far ahead or long gone) leaves
    no forms in its cache, so frames a peer sends cannot grow it without bound; one of the window is kept."""
    sender, sent = _role("A2", aggregation="broadcast")
    (first,) = _broadcasts(sender, sent, steps=1)
    receiver, _ = _role("A1", aggregation="broadcast")
    _broadcast_window(receiver, 0, own=1)
    size = len(receiver.forms)
    far = FactorDelta(sender="A2", receiver=BROADCAST, round=0, step=40, have=np.array([2]), pin=np.zeros(0),
                      digest=np.array([1, 0]), **FactorDelta.pack(40, [_form(2, 1, 40)]))
    receiver.on_factor_delta(far)
    assert len(receiver.forms) == size
    receiver.on_factor_delta(first)
    assert len(receiver.forms) == size + 1 and 2 in receiver.share.records
