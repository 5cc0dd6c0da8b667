"""Which agents are alive, counted in windows an agent listened through, not in wall time or rounds.

A window's set of forms is complete once it holds every *live* agent's; an agent silent for long is
given up on so that the others' windows complete without it. Silence only counts while this agent
was listening: a window it ran a round trip of rounds in (:meth:`Liveness.listened_through`, called
by the agent). Silence while it was itself kept off the CPU says nothing (a starved reference heard
nobody for four windows and solved the next one alone, 14 mm off), nor does one window's records lost
to loss (its next window was "exact" without them, 25-480 mm off).

Examples
--------
>>> live = Liveness()
>>> live.heard(0); live.heard(1)
>>> live.alive_members() is None  # (every agent, before two windows listened through)
True
>>> live.listened_through(); live.listened_through(); live.heard(0)
>>> sorted(live.alive_members())  # 1 was last heard two windows ago: still waited for
[0, 1]
>>> live.listened_through()
>>> sorted(live.alive_members())
[0]
"""

from __future__ import annotations

__all__ = ["Liveness"]


class Liveness:
    """When each agent (index) was last heard, in windows this agent listened through.

    Attributes
    ----------
    listened : int
        Windows this agent listened through (ran at least a round trip of rounds in): the clock.
    alive : dict
        Agent index -> :attr:`listened` when it (or its records) was last heard.
    """

    #: an agent silent for this many windows listened through is no longer waited for
    SILENT_WINDOWS = 2

    def __init__(self):
        self.listened = 0
        self.alive: dict[int, int] = {}

    def listened_through(self) -> None:
        """This agent ran a round trip of rounds in the window that just ended: silence in it counts."""
        self.listened += 1

    def heard(self, sender: int) -> None:
        """Agent ``sender`` was heard from, directly or through its records."""
        self.alive[sender] = self.listened

    def alive_members(self) -> set[int] | None:
        """Agents heard in the last :attr:`SILENT_WINDOWS` windows listened through, or since; ``None`` (every
        agent) before that many such windows."""
        if not self.alive or self.listened < self.SILENT_WINDOWS:
            return None
        return {i for i, seen in self.alive.items() if seen >= self.listened - self.SILENT_WINDOWS}
