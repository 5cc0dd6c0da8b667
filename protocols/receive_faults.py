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

import math
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from decentral.errors import InputError
from protocols.link_config import LinkConfig, link_root, link_stream
from protocols.message_base import Message

__all__ = ["Held", "ReceiveFaults", "check_faults"]


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
