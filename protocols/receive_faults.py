"""Receive-side fault injection for real transports, drawn as the simulated network draws them.

A real transport admits a frame (its signature checked) and then lets :class:`ReceiveFaults` decide
its fate with the behaviour of a :class:`protocols.link_config.LinkConfig` (``drop``, ``duplicate``,
``latency``, ``jitter``; corruption and bandwidth belong to the wire and are refused here). Each
inbound link draws from its own stream (:func:`protocols.link_config.link_stream`), six draws per
copy in the simulated network's order (drop, corrupt, duplicate, jitter, jitter of the duplicate,
corrupt position), so every process given the same ``rng`` seed draws the same fates for the same
link, and the ``k``-th frame admitted on a link meets the fate the ``k``-th copy sent on that link
meets in a :class:`protocols.network.SimulatedNetwork` of the same seed.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from decentral.errors import InputError
from protocols.link_config import LinkConfig, link_root, link_stream
from protocols.message_base import Message
from protocols.transport import Delivery, Ledger

__all__ = ["Held", "HeldCopies", "ReceiveFaults", "check_faults"]


@dataclass(frozen=True, slots=True)
class Held:
    """An admitted copy waiting for its injected delay to pass (queued as ``(arrival, order, Held)``)."""

    arrival: float
    message: Message
    sent_at: float
    size: int
    duplicate: bool


def check_faults(cfg: LinkConfig, where: str) -> None:
    """Refuse (``InputError`` naming ``where``) what a real transport cannot inject: corruption, a bandwidth cap."""
    if cfg.corrupt > 0 or math.isfinite(cfg.bandwidth):
        raise InputError("a real transport injects only drop, duplicate, latency and jitter (not corrupt or "
                         "bandwidth)", field=where)


class ReceiveFaults:
    """The faults of every inbound link and their random streams.

    Parameters
    ----------
    faults : LinkConfig
        Behaviour of every inbound link (field ``faults`` in errors).
    links : Mapping[tuple[str, str], LinkConfig]
        Per inbound link ``(sender, receiver)`` overrides (fields ``links.a->b``).
    rng : numpy.random.Generator, optional
        Draws the root of the per-link streams (once); required when any behaviour is random.
    """

    def __init__(self, faults: LinkConfig, links: Mapping[tuple[str, str], LinkConfig],
                 rng: np.random.Generator | None):
        self._links = dict(links)
        check_faults(faults, "faults")
        for pair, cfg in self._links.items():
            check_faults(cfg, f"links.{pair[0]}->{pair[1]}")
        self._faults = faults
        if rng is None and any(self.random(cfg) for cfg in (faults, *self._links.values())):
            raise InputError("random faults need an rng", field="rng")
        self._root = link_root(rng) if rng is not None else None
        self._rngs: dict[tuple[str, str], np.random.Generator] = {}

    @staticmethod
    def random(cfg: LinkConfig) -> bool:
        """Whether ``cfg`` draws anything (drop, duplicate or jitter); one that does not makes no draws."""
        return cfg.drop > 0 or cfg.duplicate > 0 or cfg.jitter > 0

    def arrivals(self, a: str, b: str, now: float) -> list[tuple[float, bool]]:
        """Fate of the next copy admitted at ``now`` on the link ``a -> b``: ``(arrival time, is duplicate)``
        per copy to hold (empty: lost)."""
        cfg = self._links.get((a, b), self._faults)
        if self.random(cfg):
            u_drop, _, u_dup, u_jit, u_jit2, _ = self._link_rng(a, b).random(6)
        else:
            u_drop, u_dup, u_jit, u_jit2 = 1.0, 1.0, 0.0, 0.0
        if u_drop < cfg.drop:
            return []
        out = [(now + cfg.latency + u_jit * cfg.jitter, False)]
        if u_dup < cfg.duplicate:
            out.append((now + cfg.latency + u_jit2 * cfg.jitter, True))
        return out

    def _link_rng(self, a: str, b: str) -> np.random.Generator:
        gen = self._rngs.get((a, b))
        if gen is None:
            gen = self._rngs[(a, b)] = link_stream(self._root, a, b)
        return gen


class HeldCopies:
    """Admitted frames after their link's faults: per local receiver, the copies held until their arrival time.

    The receive half that the socket transports share: a frame that passed every check meets its link's
    fate (:meth:`ReceiveFaults.arrivals`: lost, delayed, duplicated; counted in the ``ledger``), and its
    copies leave in arrival order (ties: admission order) once due.

    Parameters
    ----------
    faults : ReceiveFaults
        The inbound links' faults.
    ledger : Ledger
        The transport's books (``loss`` drops, ``duplicated``, ``in_flight``, ``delivered``).
    """

    def __init__(self, faults: ReceiveFaults, ledger: Ledger):
        self._faults, self._ledger = faults, ledger
        self._held: dict[str, list[tuple[float, int, Held]]] = {}
        self._order = 0

    def add(self, message: Message, receiver: str, sent_at: float, size: int, now: float) -> None:
        """An admitted frame from ``message.sender`` at ``receiver`` (``size`` bytes), read at ``now``."""
        a, kind = message.sender, message.KIND
        arrivals = self._faults.arrivals(a, receiver, now)
        if not arrivals:
            self._ledger.drop(self._ledger.keys(a, receiver, kind), size, "loss", ("in_flight", -1))
            return
        held = self._held.setdefault(receiver, [])
        for arrival, duplicate in arrivals:
            if duplicate:
                self._ledger.count(a, receiver, kind, ("duplicated", 1), ("in_flight", 1))
            self._order += 1  # ties in arrival time leave in admission order
            heapq.heappush(held, (arrival, self._order, Held(arrival, message, sent_at, size, duplicate)))

    def due(self, receiver: str, now: float) -> list[Delivery]:
        """The copies for ``receiver`` whose arrival time has come by ``now``, in arrival order."""
        held, out = self._held.get(receiver, []), []
        while held and held[0][0] <= now:
            h = heapq.heappop(held)[2]
            self._ledger.count(h.message.sender, receiver, h.message.KIND, ("in_flight", -1), ("delivered", 1),
                               ("bytes_delivered", h.size))
            out.append(Delivery(h.message, receiver, h.sent_at, h.arrival, h.size, h.duplicate))
        return out

    def next_release(self, receiver: str) -> float | None:
        """Arrival time of the earliest copy held back for ``receiver`` (None if none)."""
        held = self._held.get(receiver)
        return held[0][0] if held else None
