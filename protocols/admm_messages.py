"""Message kinds of the assembly agents' consensus-ADMM (besides ``admm.primal`` / ``admm.dual``).

``admm.config``: an assembly announces its node configuration (node id -> centre in its root
frame) valid from a step on, so that observers can name the owner of a node they detect and use its
centre ``q`` in their visual factors (seed 000 eq. (4)). Sent as a broadcast when the configuration
changes and every few steps, and unicast in answer to an ``admm.config_request``: an observer that
detects node ids it cannot name broadcasts one (again every few rounds while they stay unknown), so a
lost announcement is repaired without flooding the network.

``admm.factors``: at the cold start (the run's first step; with ``share_forms="every"`` at every
step) every agent broadcasts the cost forms of the pairs it observes over the window and of its own
odometry chain, with the list of agents whose forms it already has; an agent that sees itself missing
from that list answers with its own forms. Every agent then solves the same joint problem and starts
the ADMM at its fixed point (:mod:`agents.assembly`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from decentral.errors import ProtocolError
from protocols.messages import Message, _finite_array, _set, as_array, register

__all__ = ["ConfigAnnounce", "ConfigRequest", "FactorShare", "form_length", "pack_forms"]


@register
@dataclass(frozen=True, slots=True, eq=False, kw_only=True)
class ConfigAnnounce(Message):
    """The sender's node configuration from step ``step`` on.

    Attributes
    ----------
    step : int
        First log step at which the configuration holds.
    ids : ndarray, shape (n,), int64
        Node ids.
    centres : ndarray, shape (n, 3), float64
        Node centres in the sender's root horizontal frame (metres).
    """

    KIND: ClassVar[str] = "admm.config"

    step: int
    ids: np.ndarray
    centres: np.ndarray

    def __post_init__(self) -> None:
        Message.__post_init__(self)
        if isinstance(self.step, bool) or not isinstance(self.step, (int, np.integer)) or self.step < 0:
            raise ProtocolError("field 'step': must be a non-negative int")
        _set(self, "step", int(self.step))
        ids = as_array(self.ids, "ids", dtype=np.int64, ndim=1)
        _set(self, "ids", ids)
        _set(self, "centres", _finite_array(self.centres, "centres", shape=(ids.shape[0], 3)))
        if len(np.unique(ids)) != len(ids):
            raise ProtocolError("field 'ids': duplicate node ids")


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
        _set(self, "ids", as_array(self.ids, "ids", dtype=np.int64, ndim=1))


def form_length(m: int) -> int:
    """Floats of one packed form over ``m`` poses: upper triangle of ``M`` (3m x 3m), ``b_z`` (m), ``c_z``."""
    return 3 * m * (3 * m + 1) // 2 + m + 1


@register
@dataclass(frozen=True, slots=True, eq=False, kw_only=True)
class FactorShare(Message):
    """The sender's cost forms over the current window, so that every agent can solve the joint problem.

    The forms are the quadratic forms of :class:`decentral.admm.LocalProblem` (seed 000 eq. (4), (5),
    (7)): one per directed pair the sender observes (its visual factors) and one for its own odometry
    chain. Form ``f`` is over the poses listed in the rows of ``keys`` with first column ``f`` (in
    order); its packed floats are the upper triangle (row-major) of its ``3m x 3m`` xy form ``M``, then
    ``b_z`` (m) and ``c_z``, and the forms follow each other in ``forms``.

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
        if isinstance(self.step, bool) or not isinstance(self.step, (int, np.integer)) or self.step < 0:
            raise ProtocolError("field 'step': must be a non-negative int")
        _set(self, "step", int(self.step))
        have = as_array(self.have, "have", dtype=np.int64, ndim=1)
        if len(have) and have.min() < 0:
            raise ProtocolError("field 'have': indices must be non-negative")
        _set(self, "have", have)
        keys = as_array(np.asarray(self.keys).reshape(-1, 3), "keys", dtype=np.int64, shape=(None, 3))
        if len(keys) and (keys.min() < 0 or keys[0, 0] != 0 or np.any(np.diff(keys[:, 0]) < 0)
                          or np.any(np.diff(keys[:, 0]) > 1)):
            raise ProtocolError("field 'keys': form indices must run 0, 1, ... and all entries be non-negative")
        _set(self, "keys", keys)
        forms = _finite_array(self.forms, "forms", ndim=1)
        sizes = np.bincount(keys[:, 0]) if len(keys) else np.zeros(0, int)
        if len(forms) != sum(form_length(int(m)) for m in sizes):
            raise ProtocolError(f"field 'forms': {len(forms)} floats do not match the forms of 'keys'")
        _set(self, "forms", forms)
        pin = _finite_array(self.pin, "pin", ndim=1)
        if len(pin) not in (0, 5):
            raise ProtocolError("field 'pin': expected 0 or 5 values")
        _set(self, "pin", pin)

    def unpack(self) -> list[tuple[tuple[tuple[int, int], ...], np.ndarray, np.ndarray, float]]:
        """The forms as ``(keys ((assembly index, step), ...), M (3m, 3m), b_z (m,), c_z)``."""
        out, at = [], 0
        for f in range(int(self.keys[:, 0].max()) + 1 if len(self.keys) else 0):
            rows = self.keys[self.keys[:, 0] == f]
            m = len(rows)
            tri = 3 * m * (3 * m + 1) // 2
            M = np.zeros((3 * m, 3 * m))
            M[np.triu_indices(3 * m)] = self.forms[at:at + tri]
            M = M + np.triu(M, 1).T
            b_z = np.array(self.forms[at + tri:at + tri + m])
            c_z = float(self.forms[at + tri + m])
            at += form_length(m)
            out.append((tuple((int(a), int(s)) for _, a, s in rows), M, b_z, c_z))
        return out


def pack_forms(forms) -> tuple[np.ndarray, np.ndarray]:
    """``keys`` and ``forms`` fields of :class:`FactorShare` from ``(keys ((assembly index, step), ...), M, b_z, c_z)``."""
    keys, flat = [], []
    for f, (ks, M, b_z, c_z) in enumerate(forms):
        keys += [(f, a, s) for a, s in ks]
        flat += [np.asarray(M, float)[np.triu_indices(3 * len(ks))], np.asarray(b_z, float), [float(c_z)]]
    return (np.array(keys, dtype=np.int64).reshape(-1, 3),
            np.concatenate(flat) if flat else np.zeros(0))
