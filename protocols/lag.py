"""How late messages arrive, in rounds: the measure an agent's timeouts are scaled by.

Every message names the round its sender was in (:attr:`protocols.messages.Message.round`), and every
agent of a run counts rounds from the same start, so ``receiver's round - message.round`` is the
one-way delay of that message in rounds (link latency, queueing and the time the sender and receiver
took to get to it), measured without clocks and the same way in a simulation and between processes.
:class:`LagMeter` keeps the recent ones; an agent waits for a neighbour's answer about a round trip
(:meth:`LagMeter.round_trip`) before it calls it silent, instead of a fixed number of rounds that is
long on a quiet loopback and hopeless on a 200 ms radio.

Examples
--------
>>> meter = LagMeter()
>>> meter.round_trip()
0
>>> for lag in [8, 9, 7, 8, 10, 8]:
...     meter.observe(lag)
>>> meter.one_way(), meter.typical(), meter.round_trip()
(10, 8, 22)
"""

from __future__ import annotations

import math
from collections import deque

__all__ = ["LagMeter"]


class LagMeter:
    """The recent one-way lags of received messages, in rounds.

    Parameters
    ----------
    keep : int
        How many recent lags are kept (older ones are forgotten: a link that got faster is trusted again).
    quantile : float
        The lag that counts: this quantile (nearest rank) of the kept ones (a high one, so that jitter is
        covered).
    """

    def __init__(self, keep: int = 64, quantile: float = 0.9):
        self._lags: deque[int] = deque(maxlen=int(keep))
        self.quantile = float(quantile)
        self._cached: dict[float, int] = {}

    def observe(self, lag: int) -> None:
        """A message sent ``lag`` rounds ago arrived (negative lags, from a peer a little ahead, count as 0)."""
        self._lags.append(max(0, int(lag)))
        self._cached = {}

    def one_way(self) -> int:
        """The :attr:`quantile` of the recent lags (0 before any message arrived)."""
        return self._at(self.quantile)

    @property
    def heard(self) -> bool:
        """Whether any message arrived yet (before that, the lag is unknown, not 0)."""
        return bool(self._lags)

    def typical(self) -> int:
        """The median of the recent lags (0 before any message arrived)."""
        return self._at(0.5)

    def _at(self, q: float) -> int:
        if q not in self._cached:  # (asked every half round, changed only by arrivals)
            ranked = sorted(self._lags)  # (the nearest-rank quantile)
            self._cached[q] = ranked[max(0, math.ceil(q * len(ranked)) - 1)] if ranked else 0
        return self._cached[q]

    def round_trip(self) -> int:
        """Rounds to wait for an answer: two one-way lags plus two rounds for the peer to act on it."""
        lag = self.one_way()
        return 2 * lag + 2 if lag else 0
