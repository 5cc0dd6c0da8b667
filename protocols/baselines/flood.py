"""The raw flood: the reference every byte budget is measured against.

In the flood every agent sends its own raw step data (its cameras' detections and its odometry) to
every other agent, one :class:`RawStep` frame per agent and step. It is what a protocol that shares
data rather than estimates would cost; ``benchmarks/wire_budget.py`` measures the agents' traffic
against it on the same log, in the same framing.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from decentral.errors import ProtocolError
from protocols.fields import as_array, finite_array, set_field
from protocols.message_base import Message, register

__all__ = ["RawStep"]


@register
@dataclass(frozen=True, slots=True, eq=False, kw_only=True)
class RawStep(Message):
    """One agent's raw data of one step.

    Attributes
    ----------
    t : float
        Step time (s).
    ids : ndarray, shape (d,), int64
        Detected node ids.
    uvr : ndarray, shape (d, 3), float64
        Detection centre (u, v) and radius r (pixels).
    odometry : ndarray, shape (0,) or (4,), float64
        ``(dx, dy, dz, dtheta)`` since the previous step (Liu et al. 2024 eq. (6)), or empty.
    """

    KIND: ClassVar[str] = "raw.step"

    t: float
    ids: np.ndarray
    uvr: np.ndarray
    odometry: np.ndarray

    def __post_init__(self) -> None:
        Message.__post_init__(self)
        ids = as_array(self.ids, "ids", dtype=np.int64, ndim=1)
        set_field(self, "ids", ids)
        uvr = np.asarray(self.uvr)
        if uvr.size % 3:  # before the reshape: a decoded frame may carry any element count
            raise ProtocolError("field 'uvr': rows of (u, v, r) expected")
        uvr = finite_array(uvr.reshape(-1, 3), "uvr", ndim=2)
        if len(uvr) != len(ids):
            raise ProtocolError("field 'uvr': one row per id expected")
        set_field(self, "uvr", uvr)
        odometry = finite_array(self.odometry, "odometry", ndim=1)
        if len(odometry) not in (0, 4):
            raise ProtocolError("field 'odometry': expected 0 or 4 values")
        set_field(self, "odometry", odometry)
