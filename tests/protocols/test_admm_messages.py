"""admm.bundle and admm.bundle_ack (forms up and down the aggregation tree): round trip and rejection."""

import numpy as np
import pytest

from decentral.errors import ProtocolError
from protocols.admm_messages import FormAck, FormBundle, pack_bundle
from protocols.messages import decode


def _records():
    M = np.arange(36.0).reshape(6, 6)
    return {0: [(((0, 3), (2, 3)), M + M.T, np.array([1.0, 2.0]), 0.5, 6)],
            2: [],
            3: [(((3, 2), (3, 3)), np.eye(6), np.array([0.1, 0.2]), 0.0, 4), (((3, 3), (1, 3)), 2 * np.eye(6),
                                                                           np.array([0.3, 0.4]), 1.5, 9)]}


def _bundle(**kw):
    members, owners, keys, flat = pack_bundle(_records())
    fields = dict(sender="A3", receiver="A1", round=7, step=3, down=False, hop=2, parent=1, depth=4, start=0,
                  members=members, owners=owners, keys=keys, forms=flat, pin=np.zeros(0))
    fields.update(kw)
    return FormBundle(**fields)


def test_a_bundle_round_trips_with_every_members_forms():
    """admm.bundle decodes to an equal message whose records() give back each member's forms (none for A2)."""
    msg = _bundle()
    back = decode(msg.to_bytes())
    assert back == msg and back.down is False and back.parent == 1
    recs = back.records()
    assert sorted(recs) == [0, 2, 3] and recs[2] == [] and len(recs[3]) == 2
    for member, forms in _records().items():
        for (k, M, b, c, n), (k2, M2, b2, c2, n2) in zip(forms, recs[member]):
            assert k == k2 and np.array_equal(M, M2) and np.array_equal(b, b2) and c == c2 and n == n2


def test_a_corrupted_bundle_frame_is_refused():
    """A flipped byte in an admm.bundle frame is a ProtocolError (CRC), never a wrong bundle."""
    frame = bytearray(_bundle().to_bytes())
    frame[len(frame) // 2] ^= 0xFF
    with pytest.raises(ProtocolError):
        decode(bytes(frame))


@pytest.mark.parametrize("bad", [
    {"members": np.array([3, 0, 2])},  # not sorted
    {"owners": np.array([0, 3, 1])},  # an owner that is no member
    {"owners": np.array([0, 3])},  # fewer owners than forms
    {"hop": -1},
    {"parent": -2},
    {"down": 1},
])
def test_inconsistent_bundles_are_refused(bad):
    """Unsorted members, owners that are not members or do not match the forms, negative counts, a non-bool direction."""
    with pytest.raises(ProtocolError):
        _bundle(**bad)


def test_an_acknowledgement_round_trips_and_refuses_an_unsorted_list():
    """admm.bundle_ack decodes to an equal message; a `have` list that is not sorted and unique is refused."""
    ack = FormAck(sender="A1", receiver="A3", round=8, step=3, have=np.array([0, 1, 3]))
    assert decode(ack.to_bytes()) == ack
    with pytest.raises(ProtocolError):
        FormAck(sender="A1", receiver="A3", round=8, step=3, have=np.array([1, 1]))


def test_a_relayed_configuration_round_trips_with_its_owner():
    """admm.config relayed by A2 on behalf of A1 decodes with the same owner; a non-str owner is refused."""
    from protocols.admm_messages import ConfigAnnounce

    msg = ConfigAnnounce(sender="A2", receiver="A0", round=4, step=1, ids=np.array([7, 8]),
                         centres=np.zeros((2, 3)), owner="A1")
    back = decode(msg.to_bytes())
    assert back == msg and back.owner == "A1" and back.sender == "A2"
    with pytest.raises(ProtocolError):
        ConfigAnnounce(sender="A2", receiver="A0", round=4, step=1, ids=np.array([7]), centres=np.zeros((1, 3)),
                       owner=3)
