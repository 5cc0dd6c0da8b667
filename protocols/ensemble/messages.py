"""Messages of Funiak et al.'s distributed localization (§V), one kind per purpose, with wire encoding.

Every kind is a frozen, slotted :class:`protocols.messages.Message` (sender, receiver, round) and goes
through the project's versioned wire format. ``level`` is the depth in the hierarchy of Algorithm 1
and ``group`` the module id of the leader of the group (the set of modules one call of Algorithm 1
works on) the message belongs to, so that the groups of all concurrently active levels can share the
network. ``seq`` numbers a message that the sender retransmits until it is acknowledged (-1: sent
once, unacknowledged).

=================  ==========================================  ====================================
kind               purpose                                     phase
=================  ==========================================  ====================================
``ens.hello``      z_{sender,receiver}: neighbour detection    neighbor_detection
``ens.tree``       flood building a group's spanning tree      leader_election
``ens.join``       a module registers as its parent's child   leader_election
``ens.claim``      hop-count clustering flood                  graph_abstraction
``ens.report``     convergecast towards the group leader       per ``phase`` field
``ens.command``    dissemination from the group leader         per ``phase`` field
``ens.pose``       a module's pose, to a neighbour             rigid_alignment / refinement
``ens.ack``        acknowledges a ``seq``-numbered message     that message's phase
=================  ==========================================  ====================================
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Mapping

import numpy as np

from decentral.errors import ProtocolError
from protocols.fields import as_array, set_field
from protocols.message_base import Message, register

__all__ = [
    "PHASES",
    "SUBPHASE_OF",
    "Hello",
    "TreeFlood",
    "Join",
    "ClusterClaim",
    "GroupPayload",
    "Report",
    "Command",
    "PoseShare",
    "Ack",
]

#: phases of the distributed algorithm, in execution order (Funiak et al. 2008 Fig. 4 and Fig. 12)
PHASES: tuple[str, ...] = (
    "neighbor_detection",
    "leader_election",
    "graph_abstraction",
    "normalized_cut",
    "leaf_localization",
    "rigid_alignment",
    "refinement",
)


def _int(obj, name: str) -> None:
    v = getattr(obj, name)
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
        raise ProtocolError(f"field {name!r}: must be an int, got {type(v).__name__}")
    set_field(obj, name, int(v))


def _phase(obj) -> None:
    if obj.phase not in PHASES and obj.phase not in _SUBPHASES:
        raise ProtocolError(f"field 'phase': unknown phase {obj.phase!r}")


#: convergecast/dissemination steps; each belongs to one of PHASES (see :data:`SUBPHASE_OF`)
_SUBPHASES = {
    "count": "leader_election",
    "abstract": "graph_abstraction",
    "cut": "normalized_cut",
    "leaf": "leaf_localization",
    "boundary": "rigid_alignment",
    "align": "rigid_alignment",
    "refine": "refinement",
    "grad": "refinement",
}
SUBPHASE_OF: Mapping[str, str] = _SUBPHASES


@register
@dataclass(frozen=True, slots=True, eq=False, kw_only=True)
class Hello(Message):
    """Neighbour detection: the sender observed the receiver with sensor ``z`` (its own frame), z_{s,r}."""

    KIND: ClassVar[str] = "ens.hello"
    z: tuple
    seq: int = -1

    def __post_init__(self) -> None:
        z = tuple(float(v) for v in as_array(self.z, "z", dtype=np.float64).ravel())
        if len(z) not in (2, 3) or not all(np.isfinite(z)):
            raise ProtocolError("field 'z': need 2 or 3 finite floats")
        set_field(self, "z", z)
        Message.__post_init__(self)
        _int(self, "seq")


@register
@dataclass(frozen=True, slots=True, eq=False, kw_only=True)
class TreeFlood(Message):
    """Spanning-tree flood of group ``group`` at ``level``; the sender is ``hops`` from the leader.

    At level 0 ``group`` is the smallest module id the sender has heard of (min-id leader election).
    """

    KIND: ClassVar[str] = "ens.tree"
    level: int
    group: int
    hops: int
    seq: int = -1

    def __post_init__(self) -> None:
        Message.__post_init__(self)
        for name in ("level", "group", "hops", "seq"):
            _int(self, name)


@register
@dataclass(frozen=True, slots=True, eq=False, kw_only=True)
class Join(Message):
    """The sender chose the receiver as its parent in the tree of ``group`` at ``level``."""

    KIND: ClassVar[str] = "ens.join"
    level: int
    group: int
    seq: int = -1

    def __post_init__(self) -> None:
        Message.__post_init__(self)
        for name in ("level", "group", "seq"):
            _int(self, name)


@register
@dataclass(frozen=True, slots=True, eq=False, kw_only=True)
class ClusterClaim(Message):
    """Hop-count clustering: the sender belongs to the cluster of ``leader``, ``hops`` away from it."""

    KIND: ClassVar[str] = "ens.claim"
    level: int
    group: int
    leader: int
    hops: int
    seq: int = -1

    def __post_init__(self) -> None:
        Message.__post_init__(self)
        for name in ("level", "group", "leader", "hops", "seq"):
            _int(self, name)


def _payload(obj) -> None:
    data = obj.payload
    if not isinstance(data, Mapping):
        raise ProtocolError("field 'payload': must be a mapping of arrays")
    set_field(obj, "payload", {str(k): as_array(v, f"payload[{k}]") for k, v in data.items()})
    Message.__post_init__(obj)


@dataclass(frozen=True, slots=True, eq=False, kw_only=True)
class GroupPayload(Message):
    """The fields of a group's step: arrays by name for step ``phase`` of group ``group`` at ``level``.

    Not a kind itself: :class:`Report` (up the tree) and :class:`Command` (down it) are.
    """

    level: int
    group: int
    phase: str
    payload: Mapping[str, np.ndarray]
    seq: int = -1

    def __post_init__(self) -> None:
        _payload(self)
        for name in ("level", "group", "seq"):
            _int(self, name)
        _phase(self)


@register
@dataclass(frozen=True, slots=True, eq=False, kw_only=True)
class Report(GroupPayload):
    """Convergecast: the aggregate of the sender's subtree for step ``phase`` (arrays by name)."""

    KIND: ClassVar[str] = "ens.report"


@register
@dataclass(frozen=True, slots=True, eq=False, kw_only=True)
class Command(GroupPayload):
    """Dissemination: what the group leader decided in step ``phase`` (arrays by name)."""

    KIND: ClassVar[str] = "ens.command"


@register
@dataclass(frozen=True, slots=True, eq=False, kw_only=True)
class PoseShare(Message):
    """The sender's current pose in its group's frame: centre c (d,) then orientation matrix R (d, d)
    row-major, as ``d + d^2`` little-endian float64 packed in one ``bytes`` field (the cheapest
    encoding for the most frequent message; :attr:`position` and :attr:`rotation` unpack it).

    ``phase`` is ``boundary`` (exchange across a cut before alignment) or ``refine`` (one local
    refinement iteration, ``iteration``). Without ``seq`` a lost share leaves the receiver with the
    newest older value it holds.
    """

    KIND: ClassVar[str] = "ens.pose"
    level: int
    group: int
    phase: str
    iteration: int
    pose: bytes
    seq: int = -1

    def __post_init__(self) -> None:
        if isinstance(self.pose, bytes):
            values = np.frombuffer(self.pose, dtype="<f8") if len(self.pose) % 8 == 0 else np.zeros(0)
        else:
            values = np.asarray(self.pose, dtype="<f8").ravel()
        if values.size not in (6, 12) or not np.all(np.isfinite(values)):
            raise ProtocolError("field 'pose': need 6 (2D) or 12 (3D) finite float64 values")
        set_field(self, "pose", values.tobytes())
        Message.__post_init__(self)
        for name in ("level", "group", "iteration", "seq"):
            _int(self, name)
        _phase(self)

    @property
    def dim(self) -> int:
        """2 or 3."""
        return 2 if len(self.pose) == 48 else 3

    @property
    def position(self) -> np.ndarray:
        """Centre (d,)."""
        return np.frombuffer(self.pose, dtype="<f8")[: self.dim].copy()

    @property
    def rotation(self) -> np.ndarray:
        """Orientation matrix (d, d), module frame to the group frame."""
        d = self.dim
        return np.frombuffer(self.pose, dtype="<f8")[d:].reshape(d, d).copy()


@register
@dataclass(frozen=True, slots=True, eq=False, kw_only=True)
class Ack(Message):
    """Acknowledges the receiver's message number ``seq`` (counted in ``phase``)."""

    KIND: ClassVar[str] = "ens.ack"
    seq: int
    phase: str

    def __post_init__(self) -> None:
        Message.__post_init__(self)
        _int(self, "seq")
        _phase(self)
