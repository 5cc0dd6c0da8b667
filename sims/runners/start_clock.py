r"""Agents told different start times: found from the peers' round numbers, reported, and followed.

Every process of a run counts its rounds from its ``--start`` (:class:`sims.runners.agent_run.Pace`), and
every message carries the sender's round and, in its signed envelope, the sender's wall time ``s``
when it left. A frame of round ``r`` from a peer that started at ``S_p`` was sent at ``s >= S_p + r * T``
(``T`` the round period; the sender may have taken a while between its round and the send), so

.. math:: S - S_p \;\ge\; r\,T - (s - S)

where ``S`` is this agent's start: each frame gives a lower bound on how long before this agent the
peer started, and the largest bound over the frames heard is the estimate, within a round period.
Agents told the same start see bounds in ``(-T, 0]``; a peer that started 1 s earlier shows +1 s, one
that started 1 s later -1 s. The send time, not the arrival, is what counts: a frame read late (slow
links, or this process kept off the CPU) says nothing about the sender's start. (With the arrival
time, a stalled receiver's frames read 0.4 s after its clock was taken looked like a peer 0.4 s
ahead, and the agents of a busy 8-ring followed one another 0.8-2.3 s into the future.) The clocks
are assumed synchronized to well within the tolerance below, as the transport's replay window
assumes (``--clock-tolerance``).

:class:`StartClock` keeps these offsets. An offset beyond :meth:`StartClock.tolerance` (five
round periods, at least 0.25 s: a stalled process sees its peers' frames late) is reported (``stats["clock"]`` and a warning line of ``decentral
agent``), and the agent *follows the earliest start*: it moves its own start back to the earliest
start it has heard of, so that round numbers agree again. Starts only ever move earlier, so every
agent ends on the earliest start of the run whatever the order in which they hear each other. A
peer that claims a start more than ``follow_limit`` seconds earlier (5 s: the default clock
tolerance of the transport, beyond which its frames are refused as stale anyway) is reported but not
followed.
"""

from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["FOLLOW_LIMIT", "StartClock"]

#: seconds: a peer whose start precedes this agent's by more is reported, not followed
FOLLOW_LIMIT = 5.0


@dataclass
class StartClock:
    """Peers' start times relative to this agent's, from their round numbers (see the module's docstring).

    Attributes
    ----------
    round_period : float
        Wall seconds per round, the same for every agent.
    follow_limit : float
        Largest lead (s) of a peer's start that this agent follows.
    ahead : dict
        Peer -> seconds by which its start precedes this agent's *own* (as told) start; negative: later.
    moved : float
        Seconds by which this agent's start was moved earlier (followed).
    """

    round_period: float
    follow_limit: float = FOLLOW_LIMIT
    ahead: dict = field(default_factory=dict)
    seen: dict = field(default_factory=dict)
    moved: float = 0.0
    _epoch: int | None = None
    _frames: dict = field(default_factory=dict)

    #: frames a peer must have sent in one epoch for that epoch's estimate to be recorded in ``seen``
    MIN_FRAMES = 3

    @property
    def tolerance(self) -> float:
        """Offsets (s) within which starts count as agreeing: five round periods, at least 0.25 s."""
        return max(5.0 * self.round_period, 0.25)

    @property
    def epoch_seconds(self) -> float:
        """Length of an epoch (s) over which the bounds are maximized: 20 rounds, at least 1 s."""
        return max(20.0 * self.round_period, 1.0)

    def heard(self, sender: str, round_index: int, sent_at: float, start: float) -> None:
        """A frame of ``sender``'s round ``round_index`` sent at wall time ``sent_at`` (the sender's clock) arrived;
        this agent's rounds count from ``start`` (as moved)."""
        epoch = int(sent_at // self.epoch_seconds)
        if epoch != self._epoch:
            self._close()
            self._epoch = epoch
        bound = round_index * self.round_period - (sent_at - start) + self.moved  # relative to the start as told
        if sender not in self._frames or bound > self.ahead[sender]:
            self.ahead[sender] = bound
        self._frames[sender] = self._frames.get(sender, 0) + 1

    def _close(self) -> None:
        for peer, n in self._frames.items():
            self._record(peer, n, self.seen)
        self._frames = {}

    def _record(self, peer: str, n: int, into: dict) -> None:
        if n >= self.MIN_FRAMES and (peer not in into or abs(self.ahead[peer]) > abs(into[peer])):
            into[peer] = self.ahead[peer]

    def follow(self) -> float:
        """Seconds by which this agent's start (as told) should now be moved earlier: the earliest start heard
        of in the current epoch when it precedes this agent's by more than :attr:`tolerance` (then by more
        than what was moved plus a round; at most :attr:`follow_limit`), else what was moved already. Each frame's bound is a lower bound on the
        lead, so a start is never moved past a peer's. Updates :attr:`moved`."""
        leads = [self.ahead[p] for p in self._frames if self.ahead[p] <= self.follow_limit]
        lead = max(leads, default=0.0)
        if lead - self.moved > (self.tolerance if not self.moved else self.round_period):
            self.moved = lead  # (once moved, a closer bound moves it again as soon as it gains a round)
        return self.moved

    def offsets(self) -> dict[str, float]:
        """Peer -> seconds its start precedes this agent's own (as told; negative: later): per peer, the estimate
        of largest magnitude over the epochs in which it sent at least :attr:`MIN_FRAMES` frames (a peer that
        later followed another start is still reported), else the current epoch's."""
        out = dict(self.seen)
        for peer, n in self._frames.items():
            self._record(peer, n, out)
            out.setdefault(peer, self.ahead[peer])
        return dict(sorted(out.items()))

    def skewed(self) -> dict[str, float]:
        """Peers whose start differed from this agent's own (as told) by more than :attr:`tolerance`: peer ->
        seconds its start precedes this agent's (negative: later)."""
        return {p: d for p, d in self.offsets().items() if abs(d) > self.tolerance}

    def report(self) -> dict:
        """``stats["clock"]``: ``start_offsets`` (peer -> s its start precedes this agent's, as told; rounded to
        the millisecond), ``skewed`` (the peers beyond tolerance), ``moved`` (s this agent's start was moved
        earlier) and ``tolerance`` (s)."""
        return {"start_offsets": {p: round(d, 3) for p, d in self.offsets().items()},
                "skewed": sorted(self.skewed()), "moved": round(self.moved, 3), "tolerance": self.tolerance}
