"""The delta half of the tree aggregation: a child sends what is new, a parent rebuilds exactly or not at all."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from decentral.admm import LocalProblem
from protocols.delta_messages import DeltaBundle
from protocols.form_cache import DeltaSender, FormCache
from protocols.messages import decode


def _form(a, b, step, value):
    M = np.eye(6) * value + 0.1
    return ((a, step), (b, step)), LocalProblem((("x", step), ("y", step)), M, np.array([value, 1.0]), value)


def _records(step, window=5, scale=1.0):
    """Two members' records of the window ending at ``step``: one pair form and one odometry link per step."""
    out = {0: [], 2: []}
    for k in range(max(0, step - window + 1), step + 1):
        out[0].append(_form(0, 2, k, scale * (k + 1)))
        out[2].append(_form(2, 2, k, scale * (k + 2)))
    return out


def _send(sender, cache, records, step, parent=1):
    """A delta's trip over the wire into the parent's cache; the records the parent rebuilds."""
    carried, digests = sender.delta(parent, records, step)
    msg = decode(DeltaBundle(sender="A3", receiver="A1", round=0, step=step, hop=1, parent=parent, depth=1,
                             members=np.array(sorted(records)), pin=np.zeros(0), digest=np.array(digests),
                             **DeltaBundle.pack(step, carried)).to_bytes())
    for owner, keys, M, b_z, c_z, count in msg.carried():
        cache.remember(owner, [(keys, LocalProblem(keys, M, b_z, c_z, count))])
    first = step - 4
    return {m: cache.rebuild(m, tuple(d), first, step) for m, d in zip(msg.members.tolist(), msg.digest.tolist())}, msg


def test_after_the_first_window_a_delta_carries_one_new_step_per_form():
    """Window 1 carries everything; each later window carries one form per member (its newest step) and the
    parent rebuilds the full records of the window."""
    sender, cache = DeltaSender(), FormCache()
    rebuilt, msg = _send(sender, cache, _records(4), 4)
    assert len(msg.owners) == 10 and all(len(r) == 5 for r in rebuilt.values())
    for step in (5, 6, 7):
        sender.slide(step - 4)
        cache.slide(step - 4)
        rebuilt, msg = _send(sender, cache, _records(step), step)
        assert len(msg.owners) == 2 and sorted(msg.lags.ravel().tolist()) == [0, 0, 0, 0]
        assert all(len(r) == 5 for r in rebuilt.values())
        assert {keys[0][1] for keys, _ in rebuilt[0]} == set(range(step - 4, step + 1))


def test_a_parent_missing_older_forms_does_not_rebuild():
    """A parent whose cache lost the older forms rebuilds nothing (the child then sends the records whole)."""
    sender, cache = DeltaSender(), FormCache()
    _send(sender, cache, _records(4), 4)
    cache.clear()
    rebuilt, _ = _send(sender, cache, _records(5), 5)
    assert rebuilt == {0: None, 2: None}


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 4), st.floats(0.5, 2.0))
def test_a_changed_older_form_is_sent_again_and_rebuilt_exactly(changed, scale):
    """An older step's form whose numbers changed (a node named late) goes up again; the parent's record is
    the new one, never the stale copy."""
    sender, cache = DeltaSender(), FormCache()
    _send(sender, cache, _records(4), 4)
    records = _records(4)
    keys, old = records[0][changed]
    records[0][changed] = (keys, LocalProblem(old.keys, old.M * (1 + scale), old.b_z, old.c_z, old.count))
    rebuilt, msg = _send(sender, cache, records, 4)
    assert len(msg.owners) == 1
    new = dict(rebuilt[0])[keys]
    assert np.allclose(new.M, old.M * (1 + scale), rtol=1e-6)


def test_a_form_that_disappeared_makes_the_digest_fail():
    """A record that lost a form no longer matches what the parent holds: rebuilt as nothing, not wrongly."""
    sender, cache = DeltaSender(), FormCache()
    _send(sender, cache, _records(4), 4)
    records = _records(4)
    records[0] = records[0][1:]
    rebuilt, _ = _send(sender, cache, records, 4)
    assert rebuilt[0] is None and rebuilt[2] is not None


def test_forms_over_other_than_two_poses_are_not_sent_as_deltas():
    """A one-pose form cannot travel in a delta: the sender says so (None) and sends whole."""
    one = ((((0, 3),), LocalProblem((("x", 3),), np.eye(3), np.zeros(1), 0.0)),)
    assert DeltaSender().delta(1, {0: list(one)}, 3) is None
