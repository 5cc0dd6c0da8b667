"""Tests of the ensemble protocol messages and the aggregation halves."""

import numpy as np
import pytest

from decentral.errors import ProtocolError
from protocols.ensemble import (
    PHASES,
    SUBPHASE_OF,
    Ack,
    ClusterClaim,
    Command,
    Convergecast,
    Hello,
    Join,
    PoseShare,
    Report,
    TreeFlood,
    combine,
)
from protocols.messages import Message

BASE = dict(sender="3", receiver="7", round=11)


def _examples():
    return [
        Hello(z=np.array([0.05, 0.0]), **BASE),
        TreeFlood(level=2, group=5, hops=4, seq=9, **BASE),
        Join(level=1, group=0, **BASE),
        ClusterClaim(level=0, group=0, leader=12, hops=3, **BASE),
        Report(level=1, group=4, phase="abstract", payload={"ea": np.arange(3), "ew": np.ones(3)}, **BASE),
        Command(level=1, group=4, phase="cut", payload={"cluster_part": np.array([0, 1, 1])}, seq=2, **BASE),
        PoseShare(level=0, group=0, phase="refine", iteration=8, pose=np.r_[1.0, 2.0, np.eye(2).ravel()], **BASE),
        PoseShare(level=0, group=0, phase="boundary", iteration=0, pose=np.r_[1.0, 2.0, 3.0, np.eye(3).ravel()], **BASE),
        Ack(seq=4, phase="align", **BASE),
    ]


@pytest.mark.parametrize("msg", _examples(), ids=lambda m: m.KIND)
def test_wire_round_trip(msg):
    """Every ensemble message decodes from its wire bytes to an equal message of the same kind."""
    back = Message.from_bytes(msg.to_bytes())
    assert type(back) is type(msg) and back == msg and back.size_bytes == len(msg.to_bytes())


def test_pose_share_gives_back_the_pose():
    """A pose share returns the centre and rotation it was built from."""
    R = np.array([[0.0, -1.0], [1.0, 0.0]])
    msg = Message.from_bytes(PoseShare(level=0, group=0, phase="refine", iteration=1, pose=np.r_[0.3, -0.2, R.ravel()],
                                       **BASE).to_bytes())
    assert np.array_equal(msg.position, [0.3, -0.2]) and np.array_equal(msg.rotation, R)


def test_bad_fields_are_protocol_errors():
    """Unknown phases and malformed poses raise ProtocolError, never another exception."""
    with pytest.raises(ProtocolError):
        Report(level=0, group=0, phase="gossip", payload={}, **BASE)
    with pytest.raises(ProtocolError):
        PoseShare(level=0, group=0, phase="refine", iteration=0, pose=[1.0, 2.0], **BASE)
    with pytest.raises(ProtocolError):
        Hello(z=[np.nan, 0.0], **BASE)


def test_every_step_belongs_to_a_phase():
    """Every convergecast/dissemination step is charged to one of the declared phases."""
    assert set(SUBPHASE_OF.values()) <= set(PHASES)


def test_keyed_combine_does_not_depend_on_order():
    """Abstract-graph aggregation sums by key: any grouping of the reports gives the same totals."""
    rng = np.random.default_rng(0)
    parts = []
    for _ in range(6):
        m = 5
        parts.append({"ea": rng.integers(0, 3, m), "eb": rng.integers(0, 3, m), "ew": np.ones(m, dtype=np.int64),
                      "cid": rng.integers(0, 3, 1), "csize": np.array([1]), "cmin": rng.integers(0, 100, 1)})
    one = combine("abstract", parts)
    two = combine("abstract", [combine("abstract", parts[:2]), combine("abstract", parts[2:][::-1])])
    for k in one:
        assert np.array_equal(one[k], two[k])
    assert one["ew"].sum() == 30


def test_convergecast_waits_for_every_child():
    """A node's aggregate is ready only once each child has reported, and refuses strangers."""
    cc = Convergecast("count", [4, 9])
    cc.receive(4, {"size": np.array([3])})
    assert not cc.complete
    with pytest.raises(ProtocolError):
        cc.receive(5, {"size": np.array([1])})
    cc.receive(9, {"size": np.array([2])})
    assert cc.complete and int(cc.result({"size": np.array([1])})["size"][0]) == 6
