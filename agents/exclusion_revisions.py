"""Steps answered before a lying member was named, answered again without it.

A member whose data the others contradict is named by the first window that holds enough of its data
(the lie tests of :mod:`decentral.consistency`); the windows of the first steps may hold too little (an
odometry scaled 5x: one to three odometry links) and answer with the liar's data in, 70-230 mm off the
centralized estimate without it. When a window excludes a member that one of the last ``window``
exact windows this agent solved kept, that window is solved again without every form over the
member's poses (:meth:`protocols.window_share.WindowShare.without`): its step's answer is then
the centralized estimate of the same data without the liar, and replaces the one given
(:class:`agents.runtime.Revision`, ``reason="excluded"``, as a window that converged in the
background replaces a provisional answer). Each step is answered again once per member named later.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

from protocols.window_share import WindowShare

__all__ = ["ExclusionRevisions"]


@dataclass
class _Answered:
    """An exact window this agent solved: its step, first step, forms, and the members left out of its answer."""

    step: int
    first: int
    share: WindowShare
    left_out: frozenset


class ExclusionRevisions:
    """The last ``window`` exact windows an agent solved, to be solved again without a member named later."""

    def __init__(self, window: int):
        self._answered: deque[_Answered] = deque(maxlen=max(1, window))

    def record(self, step: int, first: int, share: WindowShare) -> None:
        """Window ``step`` (first step ``first``) was answered from the joint solution of ``share``'s kept forms."""
        self._answered.append(_Answered(step, first, share, frozenset(share.excluded)))

    def revise(self, excluded, reference: str) -> list[tuple[int, WindowShare]]:
        """``(step, window)`` for each recorded window that kept a member of ``excluded``: the window solved again
        without every such member (:meth:`~protocols.window_share.WindowShare.without`, gauge ``(reference,
        first)`` as before). A window whose rest no longer ties the gauge's variables keeps its answer."""
        out = []
        for answered in self._answered:
            named = frozenset(excluded) - answered.left_out
            if not named:
                continue
            answered.left_out |= named
            again = answered.share.without(answered.left_out - frozenset(answered.share.excluded), reference,
                                           answered.first)
            if again is not None:
                out.append((answered.step, again))
        return out
