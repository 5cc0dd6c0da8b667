"""Delta kinds: forms up the aggregation tree and by broadcast by what changed, the joint solution down, compactly.

``admm.delta`` (up): a window's cost forms go up the tree as only what the parent does not have yet
(each window adds one step of forms per pair; the older steps' forms are the same from window to
window), with a *digest* per member (how many forms its record of the window holds and the XOR of
their CRC32s), so the parent rebuilds each member's record from what it already holds and refuses
(does not acknowledge) a member it cannot rebuild exactly, which the child then sends whole.

``admm.factors_delta`` (by broadcast): the same for one agent's own forms when its window is shared by
broadcast (the cold start, slow links, a busy computer; ``admm.factors`` carried every form of the window
in float64, every window): the forms it has not broadcast before, those of the window's last two steps
again (a receiver that lost one broadcast still rebuilds the next), and the digest of its record. A
receiver that cannot rebuild the record leaves the sender out of the ``have`` list of its own broadcast,
and the sender answers it with every form.

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
from protocols.fields import as_array, finite_array, set_field
from protocols.message_base import Message, register

__all__ = ["JointPoses", "DeltaBundle", "FactorDelta", "form_crc", "record_digest"]


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


#: floats of one two-pose form on the wire: upper triangle of the 6 x 6 ``M``, ``b_z`` (2), ``c_z``, measurement count
PAIR_FORM = 25


@register
@dataclass(frozen=True, slots=True, eq=False, kw_only=True)
class DeltaBundle(Message):
    """Forms of several agents going up the tree, only those the parent lacks, and a digest per record.

    Every form shared is over two poses (a pair at one step, or an odometry link), so a form travels as
    its two assemblies, its two steps as lags behind ``step``, and its 25 numbers in float32 (the last its
    measurement count, exact in float32) (a form's
    numbers lose nothing the joint solution feels: under a micrometre and 1e-5 degree on a 64-ring).

    Attributes
    ----------
    step, hop, parent, depth : int
        As :class:`protocols.admm_messages.FormBundle` (up).
    members : ndarray, shape (h,), int16
        Agents whose records the bundle describes (sorted, unique).
    owners : ndarray, shape (F,), int16
        The member each form carried belongs to.
    pairs : ndarray, shape (F, 2), int16
        The assemblies of each form's two poses.
    lags : ndarray, shape (F, 2), uint8
        ``step`` minus the steps of each form's two poses.
    forms : ndarray, shape (25 F,), float32
        Per form: the upper triangle (row-major) of its ``6 x 6`` xy form, ``b_z`` (2), ``c_z``, its
        measurement count.
    pin : ndarray, shape (0,) or (5,), float64
        As ``FormBundle``.
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
    pairs: np.ndarray
    lags: np.ndarray
    forms: np.ndarray
    pin: np.ndarray
    digest: np.ndarray

    def __post_init__(self) -> None:
        Message.__post_init__(self)
        for name in ("step", "hop", "depth"):
            set_field(self, name, _count(getattr(self, name), name))
        set_field(self, "parent", _count(self.parent, "parent", low=-1))
        members = as_array(self.members, "members", dtype=np.int16, ndim=1)
        if len(members) and (members.min() < 0 or np.any(np.diff(members) <= 0)):
            raise ProtocolError("field 'members': must be sorted, unique and non-negative")
        set_field(self, "members", members)
        owners = as_array(self.owners, "owners", dtype=np.int16, ndim=1)
        if not np.isin(owners, members).all():
            raise ProtocolError("field 'owners': one member per form expected")
        set_field(self, "owners", owners)
        _check_pair_forms(self, len(owners))
        digest = as_array(np.asarray(self.digest).reshape(-1, 2), "digest", dtype=np.int64, ndim=2)
        if len(digest) != len(members) or (len(digest) and digest.min() < 0):
            raise ProtocolError("field 'digest': one (count, crc) row per member expected")
        set_field(self, "digest", digest)

    @staticmethod
    def pack(step: int, carried: dict) -> dict:
        """``owners``, ``pairs``, ``lags`` and ``forms`` fields from member -> ``[(keys, M (6, 6), b_z (2,), c_z, count)]``
        (every ``keys`` two ``(assembly, step)``)."""
        owners = [member for member in sorted(carried) for _ in carried[member]]
        return {"owners": np.array(owners, np.int16),
                **_pack_pair_forms(step, [f for member in sorted(carried) for f in carried[member]])}

    def carried(self) -> list[tuple[int, tuple, np.ndarray, np.ndarray, float, int]]:
        """The forms it carries: ``(owner, keys ((assembly, step), (assembly, step)), M (6, 6), b_z (2,), c_z,
        count)`` (a count that is not a non-negative integer reads as 0: unknown)."""
        return [(int(owner), *form) for owner, form in zip(self.owners.tolist(), _unpack_pair_forms(self))]


@register
@dataclass(frozen=True, slots=True, eq=False, kw_only=True)
class FactorDelta(Message):
    """One agent's forms of a window shared by broadcast, compactly: the forms it has not broadcast before
    and those of the window's last two steps (again), and a digest of its whole record of the window.

    What :class:`DeltaBundle` is to the tree's ``admm.bundle``, this is to ``admm.factors``: each window
    adds one step of forms, the older steps' forms are the same from window to window, so a receiver that
    holds the sender's earlier forms rebuilds the sender's record (:meth:`protocols.form_cache.FormCache.rebuild`)
    from what it holds and what this carries, exactly or not at all; one that cannot (it lost an earlier
    broadcast, or it only just started listening) leaves the sender out of ``have`` in its own broadcast,
    and the sender answers it with every form. Forms travel as in :class:`DeltaBundle` (two poses each,
    25 numbers in float32).

    Attributes
    ----------
    step : int
        The window's last log step.
    have : ndarray, shape (h,), int16
        As :class:`protocols.admm_messages.FactorShare`: agents whose forms of this window the sender holds,
        its own included; receivers missing from it answer with their own forms.
    pairs, lags, forms : ndarray
        The forms carried, all the sender's own (as in :class:`DeltaBundle`).
    pin : ndarray, shape (0,) or (5,), float64
        From the gauge (reference) agent: ``(step, x, y, z, theta)`` of its pose held fixed.
    digest : ndarray, shape (2,), int64
        The number of forms of the sender's record of the window and the XOR of their :func:`form_crc`.
    """

    KIND: ClassVar[str] = "admm.factors_delta"

    step: int
    have: np.ndarray
    pairs: np.ndarray
    lags: np.ndarray
    forms: np.ndarray
    pin: np.ndarray
    digest: np.ndarray

    def __post_init__(self) -> None:
        Message.__post_init__(self)
        set_field(self, "step", _count(self.step, "step"))
        have = as_array(self.have, "have", dtype=np.int16, ndim=1)
        if len(have) and have.min() < 0:
            raise ProtocolError("field 'have': indices must be non-negative")
        set_field(self, "have", have)
        _check_pair_forms(self, len(np.asarray(self.pairs).reshape(-1, 2)))
        digest = as_array(self.digest, "digest", dtype=np.int64, shape=(2,))
        if digest.min() < 0:
            raise ProtocolError("field 'digest': (count, crc) must be non-negative")
        set_field(self, "digest", digest)

    @staticmethod
    def pack(step: int, forms) -> dict:
        """``pairs``, ``lags`` and ``forms`` fields from ``[(keys, M (6, 6), b_z (2,), c_z, count)]``."""
        return _pack_pair_forms(step, forms)

    def carried(self) -> list[tuple[tuple, np.ndarray, np.ndarray, float, int]]:
        """The forms it carries as ``(keys ((assembly, step), (assembly, step)), M (6, 6), b_z (2,), c_z, count)``."""
        return _unpack_pair_forms(self)


def _check_pair_forms(msg, n: int) -> None:
    """Validate and normalize the ``pairs``, ``lags``, ``forms`` (``n`` two-pose forms) and ``pin`` fields."""
    pairs = as_array(np.asarray(msg.pairs).reshape(-1, 2), "pairs", dtype=np.int16, shape=(n, 2))
    if n and pairs.min() < 0:
        raise ProtocolError("field 'pairs': assembly indices must be non-negative")
    set_field(msg, "pairs", pairs)
    lags = as_array(np.asarray(msg.lags).reshape(-1, 2), "lags", dtype=np.uint8, shape=(n, 2))
    if n and int(lags.max()) > msg.step:
        raise ProtocolError("field 'lags': a pose before step 0")
    set_field(msg, "lags", lags)
    forms = as_array(msg.forms, "forms", dtype=np.float32, shape=(PAIR_FORM * n,))
    if not np.all(np.isfinite(forms)):
        raise ProtocolError("field 'forms': must be finite in float32")
    set_field(msg, "forms", forms)
    pin = finite_array(msg.pin, "pin", ndim=1)
    if len(pin) not in (0, 5):
        raise ProtocolError("field 'pin': expected 0 or 5 values")
    set_field(msg, "pin", pin)


def _pack_pair_forms(step: int, forms) -> dict:
    """``pairs``, ``lags`` and ``forms`` fields from ``[(keys, M (6, 6), b_z (2,), c_z, count)]`` (every ``keys``
    two ``(assembly, step)`` at most 255 steps before ``step``)."""
    pairs, lags, flat = [], [], []
    for keys, M, b_z, c_z, count in forms:
        (a1, s1), (a2, s2) = keys
        pairs.append((a1, a2)), lags.append((step - s1, step - s2))
        flat += [np.asarray(M, float)[np.triu_indices(6)], np.asarray(b_z, float), [float(c_z), float(count)]]
    return {"pairs": np.array(pairs, np.int16).reshape(-1, 2), "lags": np.array(lags, np.uint8).reshape(-1, 2),
            "forms": np.concatenate(flat) if flat else np.zeros(0)}


def _unpack_pair_forms(msg) -> list[tuple[tuple, np.ndarray, np.ndarray, float, int]]:
    """The two-pose forms of ``msg`` as ``(keys, M (6, 6), b_z (2,), c_z, count)`` (a count that is not a
    non-negative integer reads as 0: unknown)."""
    out = []
    iu = np.triu_indices(6)
    for f in range(len(msg.pairs)):
        row = np.asarray(msg.forms[PAIR_FORM * f:PAIR_FORM * (f + 1)], float)
        M = np.zeros((6, 6))
        M[iu] = row[:21]
        M = M + np.triu(M, 1).T
        keys = tuple((int(a), msg.step - int(lag)) for a, lag in zip(msg.pairs[f], msg.lags[f]))
        count = row[24]
        out.append((keys, M, row[21:23].copy(), float(row[23]),
                    int(count) if 0 <= count < 2**31 and count == int(count) else 0))
    return out


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
            set_field(self, name, _count(getattr(self, name), name))
        set_field(self, "n", _count(self.n, "n", low=1))
        set_field(self, "parent", _count(self.parent, "parent", low=-1))
        width = (self.n + 7) // 8
        for name in ("members", "index", "placeable"):
            set_field(self, name, as_array(getattr(self, name), name, dtype=np.uint8, shape=(width,)))
        edges = as_array(self.edges, "edges", dtype=np.uint8, ndim=1)
        if len(edges) not in (0, (self.n * self.n + 7) // 8):
            raise ProtocolError("field 'edges': empty or an n x n bit mask expected")
        set_field(self, "edges", edges)
        poses = finite_array(np.asarray(self.poses).reshape(-1, 4), "poses", ndim=2).astype(np.float32)
        if len(poses) != len(self.indices("index")) or not np.all(np.isfinite(poses)):
            raise ProtocolError("field 'poses': one finite row (within float32) per assembly of 'index' expected")
        poses.setflags(write=False)
        set_field(self, "poses", poses)

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
