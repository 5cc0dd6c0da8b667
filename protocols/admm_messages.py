"""Message kinds of the assembly agents' consensus-ADMM (besides ``admm.primal`` / ``admm.dual``).

``admm.config``: an assembly announces its node configuration (node id -> centre in its root
frame) valid from a step on, so that observers can name the owner of a node they detect and use its
centre ``q`` in their visual factors (Liu et al. 2024 eq. (4)). Broadcast only when the configuration
changes; re-announced every few steps by unicast to the agent's current observers, and unicast in
answer to an ``admm.config_request``: an observer that detects node ids it cannot name broadcasts one
(again every few rounds while they stay unknown), so a lost announcement is repaired without
flooding the network. Agents holding the owner's configuration answer the request too, as a relay
(``owner`` names the assembly), which never replaces what the owner said itself.

``admm.factors``: the cost forms of the pairs an agent observes over the window and of its own
odometry chain, with the list of agents whose forms it already has; an agent that sees itself
missing from that list answers with its own forms. Broadcast at the cold start and by any agent
without a route to the reference (:mod:`agents.assembly`).

``admm.bundle`` / ``admm.bundle_ack``: the same forms of several agents going up the aggregation
tree to the reference agent and the full set coming back down (:mod:`protocols.aggregation`), and a
parent's acknowledgement of a bundle from below. Every agent then solves the same joint problem and
starts the ADMM at its fixed point.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from decentral.errors import ProtocolError
from protocols.fields import as_array, finite_array, set_field
from protocols.message_base import Message, register

__all__ = ["ConfigAnnounce", "ConfigRequest", "FactorShare", "FormAck", "FormBundle", "form_length", "pack_bundle",
           "pack_forms"]


@register
@dataclass(frozen=True, slots=True, eq=False, kw_only=True)
class ConfigAnnounce(Message):
    """An assembly's node configuration from step ``step`` on (the sender's own, or relayed).

    Attributes
    ----------
    step : int
        First log step at which the configuration holds.
    ids : ndarray, shape (n,), int64
        Node ids.
    centres : ndarray, shape (n, 3), float64
        Node centres in the owner's root horizontal frame (metres).
    owner : str
        The assembly whose configuration it is; empty: the sender's own. A relay answers an
        ``admm.config_request`` on behalf of an owner whose own answer may be lost.
    """

    KIND: ClassVar[str] = "admm.config"

    step: int
    ids: np.ndarray
    centres: np.ndarray
    owner: str = ""

    def __post_init__(self) -> None:
        Message.__post_init__(self)
        if isinstance(self.step, bool) or not isinstance(self.step, (int, np.integer)) or self.step < 0:
            raise ProtocolError("field 'step': must be a non-negative int")
        set_field(self, "step", int(self.step))
        ids = as_array(self.ids, "ids", dtype=np.int64, ndim=1)
        set_field(self, "ids", ids)
        set_field(self, "centres", finite_array(self.centres, "centres", shape=(ids.shape[0], 3)))
        if len(np.unique(ids)) != len(ids):
            raise ProtocolError("field 'ids': duplicate node ids")
        if not isinstance(self.owner, str):
            raise ProtocolError("field 'owner': must be a str")


@register
@dataclass(frozen=True, slots=True, eq=False, kw_only=True)
class ConfigRequest(Message):
    """Ask the owners of node ids the sender detects but cannot name to (re-)announce their configuration.

    Attributes
    ----------
    ids : ndarray, shape (n,), int64
        The unknown node ids.
    """

    KIND: ClassVar[str] = "admm.config_request"

    ids: np.ndarray

    def __post_init__(self) -> None:
        Message.__post_init__(self)
        set_field(self, "ids", as_array(self.ids, "ids", dtype=np.int64, ndim=1))


def form_length(m: int) -> int:
    """Floats of one packed form over ``m`` poses: upper triangle of ``M`` (3m x 3m), ``b_z`` (m), ``c_z``, and
    its measurement count (:attr:`decentral.admm.LocalProblem.count`)."""
    return 3 * m * (3 * m + 1) // 2 + m + 2


@register
@dataclass(frozen=True, slots=True, eq=False, kw_only=True)
class FactorShare(Message):
    """The sender's cost forms over the current window, so that every agent can solve the joint problem.

    The forms are the quadratic forms of :class:`decentral.admm.LocalProblem` (Liu et al. 2024 eq. (4), (5),
    (7)): one per directed pair the sender observes (its visual factors) and one for its own odometry
    chain. Form ``f`` is over the poses listed in the rows of ``keys`` with first column ``f`` (in
    order); its packed floats are the upper triangle (row-major) of its ``3m x 3m`` xy form ``M``, then
    ``b_z`` (m), ``c_z`` and the form's measurement count (:attr:`decentral.admm.LocalProblem.count`, the
    degrees of freedom of the consistency test), and the forms follow each other in ``forms``.

    Attributes
    ----------
    step : int
        The window's last log step (the forms belong to that window).
    have : ndarray, shape (h,), int64
        Assembly indices (into the agents' common assembly list) whose forms of this window the sender
        already has, its own included: receivers missing from it answer with their own forms.
    keys : ndarray, shape (k, 3), int64
        Rows ``(form index, assembly index, step)``; form indices run 0, 1, ... in order.
    forms : ndarray, shape (L,), float64
        The packed forms, ``L = sum_f form_length(m_f)``.
    pin : ndarray, shape (0,) or (5,), float64
        From the gauge (reference) agent: ``(step, x, y, z, theta)`` of its pose held fixed.
    """

    KIND: ClassVar[str] = "admm.factors"

    step: int
    have: np.ndarray
    keys: np.ndarray
    forms: np.ndarray
    pin: np.ndarray

    def __post_init__(self) -> None:
        Message.__post_init__(self)
        have = as_array(self.have, "have", dtype=np.int64, ndim=1)
        if len(have) and have.min() < 0:
            raise ProtocolError("field 'have': indices must be non-negative")
        set_field(self, "have", have)
        _check_forms(self)

    def unpack(self) -> list[tuple[tuple[tuple[int, int], ...], np.ndarray, np.ndarray, float, int]]:
        """The forms as ``(keys ((assembly index, step), ...), M (3m, 3m), b_z (m,), c_z, count)``."""
        return _unpack(self.keys, self.forms)


def pack_forms(forms) -> tuple[np.ndarray, np.ndarray]:
    """``keys`` and ``forms`` fields of :class:`FactorShare` from ``(keys ((assembly index, step), ...), M, b_z, c_z,
    count)``."""
    keys, flat = [], []
    for f, (ks, M, b_z, c_z, count) in enumerate(forms):
        keys += [(f, a, s) for a, s in ks]
        flat += [np.asarray(M, float)[np.triu_indices(3 * len(ks))], np.asarray(b_z, float), [float(c_z), float(count)]]
    return (np.array(keys, dtype=np.int64).reshape(-1, 3),
            np.concatenate(flat) if flat else np.zeros(0))


def _check_forms(msg) -> None:
    """Validate and normalize the ``step``, ``keys``, ``forms`` and ``pin`` fields shared by the form kinds."""
    if isinstance(msg.step, bool) or not isinstance(msg.step, (int, np.integer)) or msg.step < 0:
        raise ProtocolError("field 'step': must be a non-negative int")
    set_field(msg, "step", int(msg.step))
    keys = as_array(np.asarray(msg.keys).reshape(-1, 3), "keys", dtype=np.int64, shape=(None, 3))
    if len(keys) and (keys.min() < 0 or keys[0, 0] != 0 or np.any(np.diff(keys[:, 0]) < 0)
                      or np.any(np.diff(keys[:, 0]) > 1)):
        raise ProtocolError("field 'keys': form indices must run 0, 1, ... and all entries be non-negative")
    set_field(msg, "keys", keys)
    forms = finite_array(msg.forms, "forms", ndim=1)
    sizes = np.bincount(keys[:, 0]) if len(keys) else np.zeros(0, int)
    if len(forms) != sum(form_length(int(m)) for m in sizes):
        raise ProtocolError(f"field 'forms': {len(forms)} floats do not match the forms of 'keys'")
    set_field(msg, "forms", forms)
    pin = finite_array(msg.pin, "pin", ndim=1)
    if len(pin) not in (0, 5):
        raise ProtocolError("field 'pin': expected 0 or 5 values")
    set_field(msg, "pin", pin)


def _unpack(keys: np.ndarray, forms: np.ndarray) -> list:
    out, at = [], 0
    for f in range(int(keys[:, 0].max()) + 1 if len(keys) else 0):
        rows = keys[keys[:, 0] == f]
        m = len(rows)
        tri = 3 * m * (3 * m + 1) // 2
        M = np.zeros((3 * m, 3 * m))
        M[np.triu_indices(3 * m)] = forms[at:at + tri]
        M = M + np.triu(M, 1).T
        b_z = np.array(forms[at + tri:at + tri + m])
        c_z = float(forms[at + tri + m])
        count = forms[at + tri + m + 1]  # (one that is not a non-negative integer reads as 0: unknown)
        at += form_length(m)
        out.append((tuple((int(a), int(s)) for _, a, s in rows), M, b_z, c_z,
                    int(count) if 0 <= count < 2**31 and count == int(count) else 0))
    return out


def _count(value, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
        raise ProtocolError(f"field {name!r}: must be a non-negative int")
    return int(value)


@register
@dataclass(frozen=True, slots=True, eq=False, kw_only=True)
class FormBundle(Message):
    """Several agents' cost forms of one window, going up or down the aggregation tree.

    The forms are those of :class:`FactorShare` (same ``keys`` / ``forms`` packing), each tagged with
    the agent it belongs to (``owners``); ``members`` lists every agent whose record the bundle holds,
    including agents with no form at all. Up: a child's own record and its subtree's, to its parent.
    Down: the full set the root collected, from parent to child (:mod:`protocols.aggregation`).

    Attributes
    ----------
    step : int
        The window's last log step.
    down : bool
        False: towards the root (convergecast); True: from the root (its final set).
    hop : int
        The sender's hop count to the root (distance vector over the view graph).
    parent : int
        The sender's parent (its index), or -1 for none (the root).
    depth : int
        Up: the largest hop count in the sender's subtree; down: in the whole tree.
    start : int
        Down: the round at which every agent starts the ADMM from the joint solution (0 up).
    members : ndarray, shape (h,), int64
        Agent indices whose records the bundle holds (sorted, unique).
    owners : ndarray, shape (F,), int64
        Per form, the agent it belongs to (each one of ``members``).
    keys : ndarray, shape (k, 3), int64
        Rows ``(form index, assembly index, step)`` as in :class:`FactorShare`.
    forms : ndarray, shape (L,), float64
        The packed forms.
    pin : ndarray, shape (0,) or (5,), float64
        The gauge agent's ``(step, x, y, z, theta)`` when its record is in the bundle.
    """

    KIND: ClassVar[str] = "admm.bundle"

    step: int
    down: bool
    hop: int
    parent: int
    depth: int
    start: int
    members: np.ndarray
    owners: np.ndarray
    keys: np.ndarray
    forms: np.ndarray
    pin: np.ndarray

    def __post_init__(self) -> None:
        Message.__post_init__(self)
        if not isinstance(self.down, (bool, np.bool_)):
            raise ProtocolError("field 'down': must be a bool")
        set_field(self, "down", bool(self.down))
        for name in ("hop", "depth", "start"):
            set_field(self, name, _count(getattr(self, name), name))
        if isinstance(self.parent, bool) or not isinstance(self.parent, (int, np.integer)) or self.parent < -1:
            raise ProtocolError("field 'parent': must be an int >= -1")
        set_field(self, "parent", int(self.parent))
        members = as_array(self.members, "members", dtype=np.int64, ndim=1)
        if len(members) and (members.min() < 0 or np.any(np.diff(members) <= 0)):
            raise ProtocolError("field 'members': must be sorted, unique and non-negative")
        set_field(self, "members", members)
        _check_forms(self)
        owners = as_array(self.owners, "owners", dtype=np.int64, ndim=1)
        n_forms = int(self.keys[:, 0].max()) + 1 if len(self.keys) else 0
        if len(owners) != n_forms or not np.isin(owners, members).all():
            raise ProtocolError("field 'owners': one member per form expected")
        set_field(self, "owners", owners)

    def records(self) -> dict[int, list]:
        """Member index -> its forms ``[(keys, M, b_z, c_z, count), ...]`` (empty list: a member with no form)."""
        out: dict[int, list] = {int(m): [] for m in self.members}
        for owner, form in zip(self.owners.tolist(), _unpack(self.keys, self.forms)):
            out[owner].append(form)
        return out


@register
@dataclass(frozen=True, slots=True, eq=False, kw_only=True)
class FormAck(Message):
    """A parent's acknowledgement of a bundle from below: the records it now holds for the window.

    Attributes
    ----------
    step : int
        The window's last log step.
    have : ndarray, shape (h,), int64
        Agent indices whose records the parent holds (sorted, unique).
    """

    KIND: ClassVar[str] = "admm.bundle_ack"

    step: int
    have: np.ndarray

    def __post_init__(self) -> None:
        Message.__post_init__(self)
        set_field(self, "step", _count(self.step, "step"))
        have = as_array(self.have, "have", dtype=np.int64, ndim=1)
        if len(have) and (have.min() < 0 or np.any(np.diff(have) <= 0)):
            raise ProtocolError("field 'have': must be sorted, unique and non-negative")
        set_field(self, "have", have)


def pack_bundle(records: dict[int, list]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``members``, ``owners``, ``keys`` and ``forms`` of :class:`FormBundle` from index -> ``[(keys, M, b_z, c_z,
    count)]``."""
    members = np.array(sorted(records), dtype=np.int64)
    owners = [int(m) for m in members for _ in records[int(m)]]
    keys, flat = pack_forms([f for m in members for f in records[int(m)]])
    return members, np.array(owners, dtype=np.int64), keys, flat
