"""admm.delta (forms up by what changed), admm.factors_delta (forms by broadcast, by what changed) and admm.solution
(the joint solution down): round trip, refusal."""

import numpy as np
import pytest

from decentral.errors import ProtocolError
from protocols.delta_messages import DeltaBundle, FactorDelta, JointPoses, form_crc, record_digest
from protocols.messages import decode


def _delta(**kw):
    M = np.arange(36.0).reshape(6, 6)
    carried = {0: [(((0, 3), (2, 3)), M + M.T, np.array([1.0, 2.0]), 0.5, 6)]}
    fields = dict(sender="A3", receiver="A1", round=7, step=3, hop=2, parent=1, depth=4,
                  members=np.array([0, 2]), pin=np.zeros(0), digest=np.array([[4, 12345], [0, 0]]),
                  **DeltaBundle.pack(3, carried))
    fields.update(kw)
    return DeltaBundle(**fields)


def _solution(**kw):
    n = 5
    fields = dict(sender="A0", receiver="A1", round=3, step=2, hop=0, parent=-1, depth=2, start=5, n=n,
                  members=JointPoses.mask(range(n), n), index=JointPoses.mask([0, 1, 3], n),
                  poses=np.array([[0, 0, 0, 0], [1.5, -0.25, 0.01, 0.3], [2.0, 1.0, 0.0, -3.1]]),
                  placeable=JointPoses.mask([1, 3], n), edges=JointPoses.mask([0 * n + 1, 1 * n + 3], n * n))
    fields.update(kw)
    return JointPoses(**fields)


def test_a_delta_round_trips_with_float32_forms_and_its_digest():
    """admm.delta decodes to an equal message; a form comes back with its keys, in float32 (24 numbers)."""
    msg = _delta()
    back = decode(msg.to_bytes())
    assert back == msg and back.forms.dtype == np.float32 and len(back.forms) == 25
    (owner, keys, M, b_z, c_z, count), = back.carried()
    M0 = np.arange(36.0).reshape(6, 6)
    assert owner == 0 and keys == ((0, 3), (2, 3)) and np.array_equal(M, M0 + M0.T)
    assert b_z.tolist() == [1.0, 2.0] and c_z == 0.5 and count == 6 and back.digest.tolist() == [[4, 12345], [0, 0]]


def test_a_forms_crc_survives_the_float32_trip():
    """form_crc of a form equals form_crc of its copy that crossed the wire (both hash float32 values)."""
    rng = np.random.default_rng(0)
    A = rng.normal(size=(6, 6)) * 1e4
    M, b_z = A @ A.T, rng.normal(size=2)
    msg = decode(_delta(members=np.array([0]), digest=np.array([[1, 0]]),
                        **DeltaBundle.pack(3, {0: [(((0, 1), (1, 1)), M, b_z, 3.25, 6)]})).to_bytes())
    (_, keys, M2, b2, c2, _), = msg.carried()
    assert keys == ((0, 1), (1, 1)) and form_crc(M, b_z, 3.25) == form_crc(M2, b2, c2)
    assert record_digest([5, 3]) == (2, 6) and record_digest([]) == (0, 0)


def test_malformed_deltas_are_refused():
    """A digest row per member, members sorted and unique, owners among the members: else ProtocolError."""
    with pytest.raises(ProtocolError):
        _delta(digest=np.array([[1, 2]]))
    with pytest.raises(ProtocolError):
        _delta(members=np.array([2, 0]))
    with pytest.raises(ProtocolError):
        _delta(members=np.array([1, 2]))
    with pytest.raises(ProtocolError):
        _delta(forms=np.zeros(23))
    with pytest.raises(ProtocolError):
        _delta(lags=np.array([[4, 0]]))


def test_a_solution_round_trips_compactly():
    """admm.solution decodes to an equal message: bit masks for the sets, float32 poses, the view graph."""
    msg = _solution()
    back = decode(msg.to_bytes())
    assert back == msg and back.indices("index") == [0, 1, 3] and back.indices("placeable") == [1, 3]
    assert back.edge_set() == {(0, 1), (1, 3)}
    assert np.allclose(back.pose_of()[1][0], [1.5, -0.25, 0.01]) and back.pose_of()[3][1] == pytest.approx(-3.1)
    assert msg.size_bytes < 400


def test_a_solution_without_edges_means_an_unchanged_view_graph():
    """An empty edges mask decodes to an empty edge set (the receiver keeps the last one)."""
    back = decode(_solution(edges=np.zeros(0, np.uint8)).to_bytes())
    assert back.edge_set() == set()


def test_malformed_solutions_are_refused():
    """Masks of the wrong width, a pose count that does not match the index, non-finite poses: refused."""
    with pytest.raises(ProtocolError):
        _solution(members=np.zeros(3, np.uint8))
    with pytest.raises(ProtocolError):
        _solution(poses=np.zeros((2, 4)))
    with pytest.raises(ProtocolError):
        _solution(poses=np.array([[0, 0, 0, 0], [np.nan, 0, 0, 0], [0, 0, 0, 0]]))
    with pytest.raises(ProtocolError):
        _solution(edges=np.zeros(2, np.uint8))


def test_every_corrupted_byte_of_a_solution_frame_is_refused():
    """A flipped byte anywhere in an admm.solution frame is a ProtocolError, never a wrong solution."""
    frame = bytearray(_solution().to_bytes())
    for i in range(len(frame)):
        bad = bytearray(frame)
        bad[i] ^= 0x41
        with pytest.raises(ProtocolError):
            decode(bytes(bad))


def _factor_delta(**kw) -> FactorDelta:
    fields = dict(sender="A2", receiver="*", round=7, step=3, have=np.array([0, 2]), pin=np.zeros(0),
                  digest=np.array([3, 999]),
                  **FactorDelta.pack(3, [(((2, 2), (1, 2)), np.eye(6), np.array([1.0, 2.0]), 0.5, 6),
                                         (((2, 3), (1, 3)), 2 * np.eye(6), np.array([0.0, -1.0]), 0.25, 4)]))
    fields.update(kw)
    return FactorDelta(**fields)


def test_a_compact_broadcast_round_trips_with_its_forms_have_list_and_digest():
    """admm.factors_delta decodes to an equal message; its forms come back with their keys (the steps from lags)."""
    msg = _factor_delta()
    back = decode(msg.to_bytes())
    assert back == msg and back.have.tolist() == [0, 2] and back.digest.tolist() == [3, 999]
    (k1, M1, b1, c1, n1), (k2, M2, b2, c2, n2) = back.carried()
    assert k1 == ((2, 2), (1, 2)) and k2 == ((2, 3), (1, 3)) and np.array_equal(M2, 2 * np.eye(6))
    assert b1.tolist() == [1.0, 2.0] and (c1, n1, c2, n2) == (0.5, 6, 0.25, 4)
    assert len(msg.to_bytes()) < len(_factor_share_of(msg).to_bytes())  # float32 and lags: smaller than admm.factors


def _factor_share_of(msg: FactorDelta):
    from protocols.admm_messages import FactorShare, pack_forms

    keys, flat = pack_forms(msg.carried())
    return FactorShare(sender=msg.sender, receiver=msg.receiver, round=msg.round, step=msg.step, have=msg.have,
                       keys=keys, forms=flat, pin=msg.pin)


@pytest.mark.parametrize("bad", [dict(digest=np.array([[1, 2]])), dict(digest=np.array([-1, 2])),
                                 dict(have=np.array([-1])), dict(lags=np.array([[4, 0], [0, 0]]))])
def test_malformed_compact_broadcasts_are_refused(bad):
    """A digest of two non-negative numbers, non-negative `have`, no pose before step 0: else ProtocolError."""
    with pytest.raises(ProtocolError):
        _factor_delta(**bad)
