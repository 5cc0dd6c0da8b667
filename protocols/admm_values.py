"""The values of the consensus rounds on the wire: the ``admm.primal``/``admm.dual`` kinds, what an agent
sends in them and what it keeps of what it hears.

Send half, :func:`value_blocks`: rows ``x`` = ``(step, R00, R01, R10, R11, px, py, pz)`` of the poses
(consensus poses in an ``admm.primal``, a pair's copies plus duals of the target in an ``admm.dual``),
``meta`` = ``(ready, rho_R, rho_p, ADMM iteration)`` and, for a dual, the penalty metric of each row
``w`` = ``(P00, P01, P02, P11, P12, P22, w_z)``.

Receive half, :class:`AdmmInbox`: the newest values heard from each neighbour, one store per role
(``targets``: the consensus of the assemblies this agent observes, from their ``admm.primal``;
``observers``: the copies of the agents that observe it, from their ``admm.dual``). Lost or late
values are explicit: a malformed message is refused (:meth:`AdmmInbox.receive` returns ``False``), a
duplicate or an overtaken (reordered) copy never replaces a newer one, and every value keeps the round
it was sent in, so the rounds use it with its age (:meth:`AdmmInbox.age`) and stop waiting for a
neighbour that stays silent. The ADMM arithmetic itself is :mod:`decentral.admm`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, ClassVar

import numpy as np

from decentral.admm import scalar_metric
from decentral.errors import ProtocolError
from protocols.fields import finite_array, finite_float, set_field
from protocols.message_base import Message, register

__all__ = ["AdmmDual", "AdmmPrimal", "Inbound", "AdmmInbox", "value_blocks", "packed_metric"]

def _blocks(value: Any, field: str) -> MappingProxyType:
    if not isinstance(value, Mapping):
        raise ProtocolError(f"field {field!r}: must map block names to float arrays")
    out = {}
    for key, arr in value.items():
        if not isinstance(key, str) or not key:
            raise ProtocolError(f"field {field!r}: block names must be non-empty str")
        out[key] = finite_array(arr, f"{field}[{key}]")
    return MappingProxyType(out)


def _window_and_blocks(msg: Message) -> None:
    """The checks every ADMM value kind makes: the base fields, an int ``window``, finite ``blocks``."""
    Message.__post_init__(msg)
    if isinstance(msg.window, bool) or not isinstance(msg.window, (int, np.integer)):
        raise ProtocolError("field 'window': must be an int")
    set_field(msg, "window", int(msg.window))
    set_field(msg, "blocks", _blocks(msg.blocks, "blocks"))


@register
@dataclass(frozen=True, slots=True, eq=False, kw_only=True)
class AdmmPrimal(Message):
    """An agent's local copies of shared variable blocks after its primal update.

    Attributes
    ----------
    window : int
        Id of the estimation window (sliding window of steps) the iteration belongs to.
    blocks : Mapping[str, ndarray]
        Block name -> finite float64 array (any shape). Names are agreed by the protocol that uses them.
    """

    KIND: ClassVar[str] = "admm.primal"

    window: int
    blocks: Mapping[str, np.ndarray]

    def __post_init__(self) -> None:
        _window_and_blocks(self)


@register
@dataclass(frozen=True, slots=True, eq=False, kw_only=True)
class AdmmDual(Message):
    """Dual variables (scaled multipliers) of shared blocks, and the penalty they are scaled by.

    Attributes
    ----------
    window : int
        Estimation window id.
    blocks : Mapping[str, ndarray]
        Block name -> finite float64 array.
    rho : float
        Positive penalty parameter the duals refer to (so peers can follow penalty adaptation).
    """

    KIND: ClassVar[str] = "admm.dual"

    window: int
    blocks: Mapping[str, np.ndarray]
    rho: float = 1.0

    def __post_init__(self) -> None:
        _window_and_blocks(self)
        rho = finite_float(self.rho, "rho")
        if rho <= 0:
            raise ProtocolError("field 'rho': must be positive")
        set_field(self, "rho", rho)


#: the age of a value never heard (larger than any wait)
NEVER = 10**9


@dataclass
class Inbound:
    """The newest ADMM values heard from one neighbour."""

    round: int
    values: dict  # step -> (R (2, 2), p (3,))
    ready: bool
    rho: tuple[float, float] = (0.0, 0.0)
    iteration: int = 0
    metrics: dict = field(default_factory=dict)  # step -> (P (3, 3), w_z): penalty metric of a dual copy
    window: int = 0  # the sender's step when it sent the values


def packed_metric(metric: tuple[np.ndarray, float]) -> list[float]:
    """``(P, w_z)`` as the wire row ``(P00, P01, P02, P11, P12, P22, w_z)``."""
    P, w_z = metric
    return [P[0, 0], P[0, 1], P[0, 2], P[1, 1], P[1, 2], P[2, 2], w_z]


def value_blocks(values: list, ready: bool, iteration: int, rho: tuple[float, float] | None = None,
                 w: np.ndarray | None = None) -> dict:
    """Wire blocks of ``values`` ``[(step, (R (2, 2), p (3,)))]``: ``x`` (m, 8), ``meta`` (4,) and, if given,
    the metric rows ``w`` (m, 7)."""
    x = np.array([[k, *v[0].ravel(), *v[1]] for k, v in values], float).reshape(-1, 8)
    rho = rho or (0.0, 0.0)
    blocks = {"x": x, "meta": np.array([1.0 if ready else 0.0, rho[0], rho[1], float(iteration)])}
    if w is not None:
        blocks["w"] = w
    return blocks


class AdmmInbox:
    """The newest values of each neighbour: ``targets`` (from ``admm.primal``) and ``observers`` (``admm.dual``)."""

    def __init__(self):
        self.targets: dict[str, Inbound] = {}
        self.observers: dict[str, Inbound] = {}

    def receive(self, message: AdmmPrimal | AdmmDual) -> bool:
        """Keep the values of ``message`` unless a newer copy is held; ``False`` if its blocks are malformed."""
        b = message.blocks
        x, meta = b.get("x"), b.get("meta")
        if x is None or meta is None or x.ndim != 2 or x.shape[1] != 8 or meta.shape != (4,):
            return False
        store = self.targets if isinstance(message, AdmmPrimal) else self.observers
        old = store.get(message.sender)
        if old is not None and old.round >= message.round:
            return True  # a duplicate or an overtaken (reordered) copy
        values = {int(row[0]): (row[1:5].reshape(2, 2).copy(), row[5:8].copy()) for row in x}
        metrics = {}
        if isinstance(message, AdmmDual):
            w = b.get("w")
            if w is not None and w.shape == (x.shape[0], 7):
                for row, wr in zip(x, w):
                    P = np.array([[wr[0], wr[1], wr[2]], [wr[1], wr[3], wr[4]], [wr[2], wr[4], wr[5]]])
                    metrics[int(row[0])] = (P, float(wr[6]))
            else:  # scalar penalties only (meta: rho_R, rho_p)
                P, w_z = scalar_metric([float(meta[1])], [float(meta[2])])
                metrics = {k: (P[0], float(w_z[0])) for k in values}
        store[message.sender] = Inbound(message.round, values, bool(meta[0] > 0.5), (float(meta[1]), float(meta[2])),
                                        int(meta[3]), metrics, int(message.window))
        return True

    @staticmethod
    def age(inbound: Inbound | None, round_index: int) -> int:
        """Rounds since ``inbound`` was sent (:data:`NEVER` for a neighbour never heard)."""
        return NEVER if inbound is None else max(0, round_index - inbound.round)

    def heard_in(self, name: str, step: int) -> bool:
        """Whether ``name`` sent values of window ``step`` or later (in either role)."""
        return any(store.get(name) is not None and store[name].window >= step
                   for store in (self.targets, self.observers))

    def remote_steps(self) -> set[int]:
        """Steps at which an observer holds copies of this assembly (factors it cannot see itself)."""
        return {k for inbound in self.observers.values() for k in inbound.values}

    def keep_from(self, step: int) -> None:
        """Forget values sent before window ``step`` (a fresh ADMM start at the new window's fixed point)."""
        self.targets = {a: v for a, v in self.targets.items() if v.window >= step}
        self.observers = {a: v for a, v in self.observers.items() if v.window >= step}
