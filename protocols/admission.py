"""Bounded cost per inbound frame: which connections may spend signature checks, and how many.

A receiver reads every frame (a read costs microseconds), refuses what is cheap to refuse without a
signature check (:meth:`protocols.auth.Gate.screen`), and only then verifies a signature (tens of
microseconds for a small frame, milliseconds for a large one). A connection that has sent a
refused frame is *suspect*; all suspect connections share one budget of signature checks per
second (:class:`SuspectBudget`), and a frame from a suspect connection that finds the budget spent
is refused as ``rate`` without its check. A connection whose frame passes every check is trusted
again, so a genuine peer that inherits a recycled connection number recovers with its first frame.
Genuine peers never send a refused frame, so they never meet the budget; an outsider's flood costs
at most the budget's checks per second, plus a read and a parse per frame.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Callable, Hashable

from protocols.auth import Rejected

if TYPE_CHECKING:
    from protocols.auth import Gate, Opened
    from protocols.message_base import Message

__all__ = ["SuspectBudget", "admit"]


class SuspectBudget:
    """A token bucket of signature checks shared by every suspect connection.

    Parameters
    ----------
    rate : float
        Checks per second refilled (a frame of ``n`` bytes costs ``1 + n / bytes_per_check`` checks).
    burst : float
        Bucket size: checks that may be spent at once after a quiet period.
    bytes_per_check : int
        Bytes that cost one more check (hashing dominates the check of a large frame).
    clock : callable
        Monotonic seconds (default :func:`time.monotonic`).

    Examples
    --------
    >>> t = [0.0]
    >>> budget = SuspectBudget(rate=2, burst=2, clock=lambda: t[0])
    >>> budget.flag(7); budget.suspect(7), budget.suspect(8)
    (True, False)
    >>> [budget.take(0) for _ in range(3)]
    [True, True, False]
    >>> t[0] = 0.5; budget.take(0)
    True
    """

    def __init__(self, rate: float = 200.0, burst: float = 50.0, bytes_per_check: int = 65536,
                 clock: Callable[[], float] = time.monotonic):
        if not (rate > 0 and burst >= 1 and bytes_per_check > 0):
            raise ValueError("rate must be > 0, burst >= 1 and bytes_per_check > 0")
        self.rate, self.burst, self.bytes_per_check = float(rate), float(burst), int(bytes_per_check)
        self._clock = clock
        self._tokens = self.burst
        self._last = clock()
        self._suspects: set[Hashable] = set()

    def suspect(self, conn: Hashable) -> bool:
        """Whether connection ``conn`` has sent a refused frame since its last genuine one."""
        return conn in self._suspects

    def flag(self, conn: Hashable) -> None:
        """Connection ``conn`` sent a refused frame."""
        self._suspects.add(conn)

    def trust(self, conn: Hashable) -> None:
        """Connection ``conn`` sent a frame that passed every check."""
        self._suspects.discard(conn)

    def take(self, nbytes: int) -> bool:
        """Spend the checks of one frame of ``nbytes`` bytes if the bucket holds them."""
        now = self._clock()
        self._tokens = min(self.burst, self._tokens + (now - self._last) * self.rate)
        self._last = now
        cost = 1.0 + nbytes / self.bytes_per_check
        if self._tokens < cost:
            return False
        self._tokens -= cost
        return True


def admit(gate: "Gate", budget: SuspectBudget, frame: bytes, source: Hashable,
          now: float | None) -> tuple["Opened", "Message"]:
    """Check one inbound ``frame`` from ``source`` (a connection or an address), cheapest checks first.

    The gate's screen (envelope, sender, replay window, clock at ``now``) runs before any signature
    check; a suspect source then spends the shared budget, and past it the frame is refused as
    ``rate`` unverified; the signature and the rest come last. A refusal other than ``rate`` makes
    the source suspect; a frame that passes trusts it again.

    Raises
    ------
    protocols.auth.Rejected
        With the reason of the first failing check.
    """
    try:
        env = gate.screen(frame, now)
        if budget.suspect(source) and not budget.take(len(frame)):
            raise Rejected("rate", "a sender that sent refused frames, past the budget of checks")
        message = gate.verify(env)
    except Rejected as err:
        if err.reason != "rate":
            budget.flag(source)
        raise
    budget.trust(source)
    return env, message
