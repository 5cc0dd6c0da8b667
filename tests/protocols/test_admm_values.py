"""ADMM values on the wire: blocks round-trip; the inbox keeps the newest copy per neighbour and refuses malformed ones."""

import numpy as np

from decentral.admm import scalar_metric
from decentral.geometry import rot2
from protocols.admm_values import NEVER, AdmmInbox, packed_metric, value_blocks
from protocols.messages import AdmmDual, AdmmPrimal, decode


def _values(shift=0.0, steps=(3, 4)):
    return [(k, (rot2(0.1 * k + shift), np.array([k + shift, 1.0, 0.5]))) for k in steps]


def _primal(sender="A1", round_index=5, window=4, shift=0.0, ready=True, iteration=2):
    return AdmmPrimal(sender=sender, receiver="A0", round=round_index, window=window,
                      blocks=value_blocks(_values(shift), ready, iteration))


def _metric(k):
    P = np.array([[2.0 + k, 0.1, 0.2], [0.1, 3.0, 0.3], [0.2, 0.3, 4.0]])
    return P, 5.0 + k


def test_values_round_trip_through_the_wire_into_the_inbox():
    """A primal's poses, ready flag, iteration and window come back exactly after encode/decode."""
    inbox = AdmmInbox()
    assert inbox.receive(decode(_primal(iteration=7).to_bytes()))
    got = inbox.targets["A1"]
    for k, (R, p) in _values():
        assert np.array_equal(got.values[k][0], R) and np.array_equal(got.values[k][1], p)
    assert got.ready and got.iteration == 7 and got.window == 4 and got.round == 5 and not inbox.observers


def test_a_duals_metric_rows_are_rebuilt_as_symmetric_matrices():
    """A dual's `w` rows give back each step's (P, w_z); without them the scalar penalties of `meta` apply."""
    values = _values()
    w = np.array([packed_metric(_metric(k)) for k, _ in values])
    inbox = AdmmInbox()
    inbox.receive(AdmmDual(sender="A2", receiver="A0", round=1, window=4,
                           blocks=value_blocks(values, False, 1, rho=(2.0, 3.0), w=w)))
    for k, _ in values:
        P, w_z = inbox.observers["A2"].metrics[k]
        assert np.array_equal(P, _metric(k)[0]) and w_z == _metric(k)[1]
    inbox.receive(AdmmDual(sender="A3", receiver="A0", round=1, window=4,
                           blocks=value_blocks(values, False, 1, rho=(2.0, 3.0))))
    P0, w0 = scalar_metric([2.0], [3.0])
    assert all(np.array_equal(P, P0[0]) and w_z == float(w0[0]) for P, w_z in inbox.observers["A3"].metrics.values())


def test_a_duplicate_or_overtaken_copy_never_replaces_a_newer_one():
    """Reordered delivery: a copy sent in an earlier (or the same) round than the held one is dropped."""
    inbox = AdmmInbox()
    inbox.receive(_primal(round_index=8, shift=1.0))
    assert inbox.receive(_primal(round_index=6, shift=2.0)) and inbox.receive(_primal(round_index=8, shift=3.0))
    assert inbox.targets["A1"].round == 8 and inbox.targets["A1"].values[3][1][0] == 4.0
    inbox.receive(_primal(round_index=9, shift=5.0))
    assert inbox.targets["A1"].values[3][1][0] == 8.0


def test_malformed_blocks_are_refused_and_nothing_is_kept():
    """Missing or misshapen `x`/`meta` blocks: receive returns False and the stores stay empty."""
    inbox = AdmmInbox()
    good = value_blocks(_values(), True, 1)
    for blocks in ({"x": good["x"]}, {"meta": good["meta"]}, {"x": good["x"][:, :7], "meta": good["meta"]},
                   {"x": good["x"], "meta": good["meta"][:3]}, {"x": good["x"].ravel(), "meta": good["meta"]}):
        assert not inbox.receive(AdmmPrimal(sender="A1", receiver="A0", round=1, window=0, blocks=blocks))
    assert not inbox.targets and not inbox.observers


def test_a_silent_neighbour_ages_and_one_never_heard_is_infinitely_old():
    """Age = rounds since the held copy was sent (never negative); `NEVER` without a copy."""
    inbox = AdmmInbox()
    inbox.receive(_primal(round_index=5))
    assert inbox.age(inbox.targets["A1"], 12) == 7 and inbox.age(inbox.targets["A1"], 3) == 0
    assert inbox.age(inbox.targets.get("A9"), 12) == NEVER


def test_a_new_window_forgets_values_of_older_windows_only():
    """keep_from(step) drops copies sent before window `step`, in both roles; heard_in follows."""
    inbox = AdmmInbox()
    inbox.receive(_primal(sender="A1", window=3))
    inbox.receive(_primal(sender="A2", window=4))
    inbox.receive(AdmmDual(sender="A3", receiver="A0", round=1, window=3, blocks=value_blocks(_values(), True, 1)))
    assert inbox.heard_in("A3", 3) and not inbox.heard_in("A3", 4)
    inbox.keep_from(4)
    assert list(inbox.targets) == ["A2"] and not inbox.observers and inbox.remote_steps() == set()


def test_remote_steps_are_the_steps_observers_hold_copies_of():
    """The steps of this assembly's pose that some observer holds copies of (from their duals)."""
    inbox = AdmmInbox()
    inbox.receive(AdmmDual(sender="A3", receiver="A0", round=1, window=4,
                           blocks=value_blocks(_values(steps=(2, 4)), True, 1)))
    inbox.receive(AdmmDual(sender="A2", receiver="A0", round=1, window=4,
                           blocks=value_blocks(_values(steps=(3,)), True, 1)))
    assert inbox.remote_steps() == {2, 3, 4}
