"""Pieces of the batched refinement: wire sizes and group-tree shape."""

import numpy as np

from agents.modules.batched import _digits, _size_base
from protocols.ensemble.messages import Command, PoseShare, Report


def test_digits_are_name_lengths():
    """The name length of a module id is the length of its decimal string."""
    ids = np.array([0, 1, 9, 10, 99, 100, 12345, 20000])
    assert _digits(ids).tolist() == [len(str(k)) for k in ids.tolist()]


def test_size_base_plus_names_is_the_wire_size():
    """A refinement message's wire size is its fixed part plus the lengths of the two names."""
    for d in (2, 3):
        pose = np.arange(d + d * d, dtype=float)
        base = _size_base(PoseShare(sender="0", receiver="0", round=0, level=0, group=0, phase="refine",
                                    iteration=0, pose=pose))
        msg = PoseShare(sender="12345", receiver="678", round=99, level=7, group=4321, phase="refine",
                        iteration=55, pose=pose)
        assert msg.size_bytes == base + 8
    rep = Report(sender="0", receiver="0", round=0, level=0, group=0, phase="grad", payload={"g": np.array([0.0])})
    big = Report(sender="19999", receiver="3", round=5, level=2, group=17, phase="grad", payload={"g": np.array([3.5])})
    assert big.size_bytes == _size_base(rep) + 6
    cmd = Command(sender="0", receiver="0", round=0, level=0, group=0, phase="grad",
                  payload={"stop": np.array([False]), "g": np.array([0.0])})
    big = Command(sender="42", receiver="420", round=5, level=2, group=17, phase="grad",
                  payload={"stop": np.array([True]), "g": np.array([0.25])})
    assert big.size_bytes == _size_base(cmd) + 5
