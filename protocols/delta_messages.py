"""Delta kinds of the aggregation tree: forms up by what changed, the joint solution down, compactly.

``admm.delta`` (up): a window's cost forms go up the tree as only what the parent does not have yet
(each window adds one step of forms per pair; the older steps' forms are the same from window to
window), with a *digest* per member (how many forms its record of the window holds and the XOR of
their CRC32s), so the parent rebuilds each member's record from what it already holds and refuses
(does not acknowledge) a member it cannot rebuild exactly, which the child then sends whole.

``admm.solution`` (down): the joint solution of a window coming down the aggregation tree, compactly.

Once the reference agent holds every live agent's cost forms of a window it solves the joint problem
(:func:`decentral.admm.solve_joint`) and sends the answer down the tree instead of the forms: the
newest step's pose of every assembly tied to the gauge (float32: 4 bytes per number, well under a
micrometre and a microradian at the scales of a swarm), which assemblies the centralized placement
test places relative to the reference, and the view graph the forms revealed (each agent's place in
the next window's tree). Its size grows with the number of assemblies, ``~24 n`` bytes, where the
forms it replaces grow with the number of pairs times the window.

The other kinds stay as they were (``admm.bundle`` still carries forms, up the tree, and down when the
reference timed out with a partial set); a receiver that does not know this kind refuses it cleanly
(unknown kind id).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from decentral.errors import ProtocolError
from protocols.admm_messages import _check_forms, _unpack
from protocols.messages import Message, _finite_array, _set, as_array, register

__all__ = ["JointPoses", "DeltaBundle", "form_crc", "record_digest"]


def form_crc(M: np.ndarray, b_z: np.ndarray, c_z: float) -> int:
    """CRC32 of a form's numbers as a delta carries them (upper triangle of ``M``, ``b_z``, ``c_z``, in
    float32), so that a form and its copy that crossed the wire have the same CRC."""
    import zlib

    M = np.asarray(M, float)
    data = np.concatenate([M[np.triu_indices(len(M))], np.asarray(b_z, float), [float(c_z)]])
    return zlib.crc32(np.ascontiguousarray(data, dtype="<f4").tobytes()) & 0x7FFFFFFF


def record_digest(crcs) -> tuple[int, int]:
    """``(count, XOR of the CRCs)`` of a record's forms (order-free)."""
    crcs = list(crcs)
    x = 0
    for c in crcs:
        x ^= int(c)
    return len(crcs), x


@register
@dataclass(frozen=True, slots=True, eq=False, kw_only=True)
class DeltaBundle(Message):
    """Forms of several agents going up the tree, only those the parent lacks, with the window's manifest.

    Attributes
    ----------
    step, hop, parent, depth : int
        As :class:`protocols.admm_messages.FormBundle` (up).
    members : ndarray, shape (h,), int64
        Agents whose records the bundle describes (sorted, unique).
    owners, keys, forms, pin
        The forms carried (those the parent lacks), packed as in ``FormBundle`` but keys in int32
        and forms in float32.
    digest : ndarray, shape (h, 2), int64
        Per member (in the order of ``members``): the number of forms of its record of the window and
        the XOR of their :func:`form_crc`.
    """

    KIND: ClassVar[str] = "admm.delta"

    step: int
    hop: int
    parent: int
    depth: int
    members: np.ndarray
    owners: np.ndarray
    keys: np.ndarray
    forms: np.ndarray
    pin: np.ndarray
    digest: np.ndarray

    def __post_init__(self) -> None:
        Message.__post_init__(self)
        for name in ("hop", "depth"):
            _set(self, name, _count(getattr(self, name), name))
        _set(self, "parent", _count(self.parent, "parent", low=-1))
        members = as_array(self.members, "members", dtype=np.int64, ndim=1)
        if len(members) and (members.min() < 0 or np.any(np.diff(members) <= 0)):
            raise ProtocolError("field 'members': must be sorted, unique and non-negative")
        _set(self, "members", members)
        _check_forms(self)
        # on the wire: keys int32, forms float32 (a form's numbers lose nothing the joint solution feels:
        # under a micrometre and 1e-5 degree on a 64-ring)
        keys = self.keys.astype(np.int32)
        keys.setflags(write=False)
        _set(self, "keys", keys)
        forms = self.forms.astype(np.float32)
        if not np.all(np.isfinite(forms)):
            raise ProtocolError("field 'forms': must be finite in float32")
        forms.setflags(write=False)
        _set(self, "forms", forms)
        owners = as_array(self.owners, "owners", dtype=np.int64, ndim=1)
        n_forms = int(self.keys[:, 0].max()) + 1 if len(self.keys) else 0
        if len(owners) != n_forms or not np.isin(owners, members).all():
            raise ProtocolError("field 'owners': one member per form expected")
        _set(self, "owners", owners)
        digest = as_array(np.asarray(self.digest).reshape(-1, 2), "digest", dtype=np.int64, ndim=2)
        if len(digest) != len(members) or (len(digest) and digest.min() < 0):
            raise ProtocolError("field 'digest': one (count, crc) row per member expected")
        _set(self, "digest", digest)

    def carried(self) -> list[tuple[int, tuple, np.ndarray, np.ndarray, float]]:
        """The forms it carries: ``(owner, keys, M, b_z, c_z)``."""
        return [(int(o), keys, M, b_z, c_z) for o, (keys, M, b_z, c_z) in zip(self.owners.tolist(),
                                                                               _unpack(self.keys, self.forms))]


def _count(value, name: str, low: int = 0) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        raise ProtocolError(f"field {name!r}: must be an int >= {low}")
    return int(value)


@register
@dataclass(frozen=True, slots=True, eq=False, kw_only=True)
class JointPoses(Message):
    """The joint solution of the window ending at ``step``, from the reference agent, down the tree.

    Sets of assemblies travel as bit masks over the ``n`` assemblies (``numpy.packbits``, ``ceil(n/8)``
    bytes) and the view graph as an ``n x n`` adjacency bit mask.

    Attributes
    ----------
    step : int
        The window's last log step.
    hop, parent, depth : int
        The sender's hop count to the reference, its parent index (-1: none) and the tree's depth.
    start : int
        The round at which the agents start (as :class:`protocols.admm_messages.FormBundle`).
    n : int
        Number of assemblies.
    members : ndarray, shape (ceil(n/8),), uint8
        Agents whose forms the solution sums.
    index : ndarray, shape (ceil(n/8),), uint8
        Assemblies with a pose (tied to the gauge).
    poses : ndarray, shape (m, 4), float32
        ``(x, y, z, theta)`` of each assembly of ``index`` (in index order) at ``step``, in the gauge
        (the reference's frame at the window's first step), metres and radians.
    placeable : ndarray, shape (ceil(n/8),), uint8
        Assemblies the centralized placement test places relative to the reference at ``step``.
    edges : ndarray, shape (0,) or (ceil(n*n/8),), uint8
        Observing pairs as bits ``observer * n + target``; empty: as in the last solution.
    """

    KIND: ClassVar[str] = "admm.solution"

    step: int
    hop: int
    parent: int
    depth: int
    start: int
    n: int
    members: np.ndarray
    index: np.ndarray
    poses: np.ndarray
    placeable: np.ndarray
    edges: np.ndarray

    def __post_init__(self) -> None:
        Message.__post_init__(self)
        for name in ("step", "hop", "depth", "start"):
            _set(self, name, _count(getattr(self, name), name))
        _set(self, "n", _count(self.n, "n", low=1))
        _set(self, "parent", _count(self.parent, "parent", low=-1))
        width = (self.n + 7) // 8
        for name in ("members", "index", "placeable"):
            _set(self, name, as_array(getattr(self, name), name, dtype=np.uint8, shape=(width,)))
        edges = as_array(self.edges, "edges", dtype=np.uint8, ndim=1)
        if len(edges) not in (0, (self.n * self.n + 7) // 8):
            raise ProtocolError("field 'edges': empty or an n x n bit mask expected")
        _set(self, "edges", edges)
        poses = _finite_array(np.asarray(self.poses).reshape(-1, 4), "poses", ndim=2).astype(np.float32)
        if len(poses) != len(self.indices("index")) or not np.all(np.isfinite(poses)):
            raise ProtocolError("field 'poses': one finite row (within float32) per assembly of 'index' expected")
        poses.setflags(write=False)
        _set(self, "poses", poses)

    @staticmethod
    def mask(indices, n: int) -> np.ndarray:
        """The bit mask of ``indices`` over ``n`` assemblies (``n * n`` for edges ``a * n + b``)."""
        bits = np.zeros(n, bool)
        bits[list(indices)] = True
        return np.packbits(bits)

    def indices(self, name: str) -> list[int]:
        """The assemblies in mask field ``name`` (``members``, ``index`` or ``placeable``), sorted."""
        return np.flatnonzero(np.unpackbits(getattr(self, name))[: self.n]).tolist()

    def edge_set(self) -> set[tuple[int, int]]:
        """The observing pairs ``(observer, target)`` (empty: unchanged since the last solution)."""
        flat = np.flatnonzero(np.unpackbits(self.edges)[: self.n * self.n]) if len(self.edges) else []
        return {(int(e) // self.n, int(e) % self.n) for e in flat}

    def pose_of(self) -> dict[int, tuple[np.ndarray, float]]:
        """Assembly index -> (position (3,) float64, yaw)."""
        return {i: (np.asarray(row[:3], float), float(row[3])) for i, row in zip(self.indices("index"), self.poses)}
