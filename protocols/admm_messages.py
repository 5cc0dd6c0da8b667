"""Message kinds of the assembly agents' consensus-ADMM (besides ``admm.primal`` / ``admm.dual``).

``admm.config``: an assembly announces its node configuration (node id -> centre in its root
frame) valid from a step on, so that observers can name the owner of a node they detect and use its
centre ``q`` in their visual factors (seed 000 eq. (4)). Sent as a broadcast when the configuration
changes and every few steps, and unicast in answer to an ``admm.config_request``: an observer that
detects node ids it cannot name broadcasts one (again every few rounds while they stay unknown), so a
lost announcement is repaired without flooding the network.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from decentral.errors import ProtocolError
from protocols.messages import Message, _finite_array, _set, as_array, register

__all__ = ["ConfigAnnounce", "ConfigRequest"]


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
