"""One agent, two runtimes: the local window rule and the host that drives an agent over a transport.

The agent logic (:class:`agents.assembly.AssemblyAgent`) does not know whether it runs inside a
simulation or as an operating-system process: a *runtime* owns the clock, the inbox and the timers
and calls the same three things in both cases, once per half round:

1. hand it what arrived (:meth:`LocalAgent.receive`),
2. let it run the half round if it has work (:meth:`LocalAgent.half_round`), and
3. send what it queued.

:class:`AgentHost` does exactly this on any :class:`protocols.transport.Transport`; the simulated
runner (:func:`sims.runners.admm_run.run_admm`) calls it for every agent in simulated time over the
:class:`protocols.network.SimulatedNetwork`, and ``decentral agent`` (:mod:`sims.cli.agent`) calls it
for one agent in wall-clock time over the socket transport.

**The local rule** (:class:`WindowRule`): there is no global "all converged" flag. Each agent
decides alone that its window is done: once its own convergence test has held for ``settle``
consecutive rounds (after at least ``min_rounds``), or when the round budget between two sensor
steps is spent. It then goes *quiet*: it still handles every message (answers to configuration
requests, lost bundles and acknowledgements come out of the handlers), but runs ADMM half rounds
only to answer a neighbour whose window is not done yet (ADMM values without the ``done`` block in
two of the last four rounds), so a late neighbour is never left waiting for values, and two quiet agents
exchange nothing. An answer that moves it off its own convergence test makes it busy again.

**A window that outlives its step** (:attr:`WindowRule.background`): when the next sensor step comes
before an agent's window is done, the step is answered provisionally (the joint solution of the forms
held) and the unfinished window keeps going in the background (a fork of the agent,
:meth:`agents.assembly.AssemblyAgent.fork`) beside the new one, until the step after: the messages of
its window (forms, solutions, ADMM values) go to it, and only those of its window leave it. If it
converges in that time, its answer replaces the provisional one (:class:`Revision`,
:meth:`LocalAgent.take_revisions`), at most one sensor step late. If it does not, but the forms it holds
when it ends place an assembly the provisional answer left out (and every one it placed), the joint
solution of those forms replaces the provisional answer, still provisional (``reason="more_forms"``):
what the centralized estimator gives on the data that arrived within one more step. The new window never
sees ADMM values of an older one (they would overwrite a neighbour's newer values in its inbox). The log's
last step is no exception: when its next step would be due, the runtime calls :meth:`LocalAgent.end_of_log`
and an unfinished last window goes on in the background for that one more step period too, then
:meth:`LocalAgent.end_background`.

A simulation therefore predicts what processes do: the simulated runner starts the next step when
every live agent is quiet and nothing is in flight, which is what processes do while they wait for
the next sensor step (tested: running the whole budget changes no estimate and no message count).
The estimate of a step (:attr:`LocalAgent.window_estimate`) is what the agent holds when its window
is done (again, if an answer made it busy), or when the next step comes before that.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from agents.assembly import AssemblyAgent, OwnStep
from decentral.errors import InputError
from decentral.observations import PlanarPose
from protocols.admm_messages import ConfigAnnounce, FactorShare, FormAck, FormBundle
from protocols.delta_messages import DeltaBundle, FactorDelta, JointPoses
from protocols.messages import AdmmDual, AdmmPrimal, Message
from protocols.transport import Transport

__all__ = ["WindowRule", "Revision", "LocalAgent", "AgentHost", "window_of"]

_BY_STEP = (FactorShare, FactorDelta, FormBundle, FormAck, DeltaBundle, JointPoses)


def window_of(message: Message) -> int | None:
    """The window (newest log step) a message belongs to, or ``None`` for messages of no one window
    (configurations, requests, heartbeats)."""
    if isinstance(message, (AdmmPrimal, AdmmDual)):
        return int(message.window)
    if isinstance(message, _BY_STEP):
        return int(message.step)
    return None


@dataclass(frozen=True)
class Revision:
    """A step answered again: its window converged in the background after a provisional answer, or a later
    window excluded a member whose data it kept (:mod:`agents.exclusion_revisions`).

    Attributes
    ----------
    step : int
        The log step.
    poses : dict
        Assembly -> :class:`PlanarPose` relative to the agent, the new answer.
    unplaced : dict
        Assembly -> why it is not placed.
    rounds : int
        Rounds the window took in all, from its step's arrival (``"excluded"``: 0, no round of its own).
    reason : str
        ``"background"`` (converged in the background), ``"more_forms"`` (the background window ended
        unconverged, but the forms it then held place an assembly the first answer left out: the joint
        solution of those, still provisional) or ``"excluded"``.
    without : tuple of str
        Agents whose forms the converged window lacked (given up on as down; :attr:`AssemblyAgent.without`).
    converged : bool
        Whether the new answer is a converged window's (``False`` only for ``"more_forms"``).
    """

    step: int
    poses: dict
    unplaced: dict
    rounds: int
    reason: str = "background"
    without: tuple = ()
    converged: bool = True


@dataclass(frozen=True)
class WindowRule:
    """When one agent considers its window done, by itself.

    Attributes
    ----------
    min_rounds : int
        Rounds of the window before the convergence test may end it.
    settle : int
        Consecutive rounds the agent's own convergence flag must hold.
    budget : int
        Rounds between two sensor steps: at this count the window ends whatever the test says (a
        process at the log's pace has ``step period / round period`` of them).
    background : bool
        A window not done when the next sensor step comes keeps going beside the next one until the step
        after, and revises its step's provisional answer if it converges (only where every window
        shares its forms: a plain consensus-ADMM carries its iterates from window to window instead).
    """

    min_rounds: int = 2
    settle: int = 2
    budget: int = 300
    background: bool = True

    def __post_init__(self) -> None:
        if not (self.budget >= 1 and self.settle >= 1 and self.min_rounds >= 0):
            raise InputError("need budget >= 1, settle >= 1, min_rounds >= 0", field="budget")

    def share_timeout(self, default: int) -> int:
        """The wait for a window's forms under this budget: ``default`` (:attr:`AgentConfig.share_timeout`),
        at most half the budget and at least 4 rounds, so that a window whose peer is down still ends
        with the others' forms before the next sensor step comes."""
        return max(4, min(default, self.budget // 2))


class LocalAgent:
    """An :class:`AssemblyAgent` plus the local window rule (what a runtime drives).

    Parameters
    ----------
    agent : AssemblyAgent
        The protocol logic.
    rule : WindowRule
        When its window is done.
    """

    def __init__(self, agent: AssemblyAgent, rule: WindowRule = WindowRule()):
        self.agent = agent
        self.rule = rule
        self.step: int | None = None
        self.rounds = 0  # rounds run (or waited through) in the current window
        self.streak = 0
        self.done = False
        self.converged = False  # the window ended by the convergence test, not by the budget
        self.window_estimate: dict[str, PlanarPose] = {}
        self.window_unplaced: dict[str, str] = {}  # assembly -> why it is not in window_estimate
        self._ticked = False
        self._heard: set[int] = set()  # rounds (of this window, after it was done) with values from a busy neighbour
        #: the previous window, still at work beside this one (see the module docstring), or None
        self.background: LocalAgent | None = None
        self._next_background: LocalAgent | None = None  # the window end_window kept going, until the next step
        self._revised = False  # (of a background window) its revision was taken, or it ended for good
        self._answered: frozenset = frozenset()  # (of a background window) what its step's provisional answer placed
        self._revisions: list[Revision] = []
        self._over = False  # the log's last step is over (end_of_log): its window's messages go to the background

    @property
    def name(self) -> str:
        return self.agent.name

    @property
    def quiet(self) -> bool:
        """Done with its window (and its background window, if any) and nobody to answer: it sends nothing of
        its own accord (:attr:`idle`)."""
        return self.idle and (self.background is None or self.background.idle)

    @property
    def idle(self) -> bool:
        """Done with its own window and nobody to answer.

        A neighbour's values without the ``done`` block in one round after this agent was done may be its
        last ones (it finished in the same round); in two of the four rounds before this one, it is still
        at work and waiting for this agent's values (behind a lossy link that drops every other copy), so
        the agent runs this whole round (both phases) to answer. (Requiring two rounds running instead left
        neighbours at work alone under 50 % loss: 6 of 8 cold starts of a 4-ring hit the 600-round cap.)
        """
        r = self.rounds  # index of the round under way (rounds completed in this window)
        return self.done and len({r - 1, r - 2, r - 3, r - 4} & self._heard) < 2

    def on_step(self, own: OwnStep, round_index: int | None = None) -> None:
        """A new sensor step at round ``round_index``: the previous window ends here (:meth:`end_window`)."""
        self._hand_over()
        self.agent.on_step(own, round_index)
        self.step = own.step
        self.rounds = self.streak = 0
        self.done = self.converged = False
        self._heard = set()
        self.agent.window_done = False
        self.window_estimate = {}
        self.window_unplaced = {}

    def _hand_over(self) -> None:
        """The time of a next sensor step: the window ends (:meth:`end_window`), the background window of the step
        before ends for good (answered again if its forms place more), and an unfinished window goes on in the
        background."""
        self.end_window()
        self.end_background()
        self.background, self._next_background = self._next_background, None

    def end_of_log(self) -> None:
        """The log's last step is over (its next step would be due now): the last window ends like every other and,
        if it ended unconverged, goes on in the background for one more step period, as every other window does
        (a runtime then calls :meth:`end_background`). Until then the agent still handles every other message;
        the messages of that window go to the background window alone."""
        self._hand_over()
        self._over = True

    def end_background(self) -> None:
        """The background window ends for good (the step after its own has come, or the run is over): if it did not
        converge but the forms it holds place more, its step is answered again (:meth:`_answer_again`)."""
        if self.waiting_in_background:
            self._answer_again(self.background)
            self.background._revised = True

    @property
    def waiting_in_background(self) -> bool:
        """A background window is still at work on an unconverged step (whose answer may yet change)."""
        return self.background is not None and not self.background._revised

    def _fork(self) -> "LocalAgent":
        """This window as it is now, to go on in the background until the step after the next."""
        twin = LocalAgent(self.agent.fork(), dataclasses.replace(self.rule, background=False,
                                                                  budget=2 * self.rule.budget))
        twin.step, twin.rounds, twin.streak = self.step, self.rounds, self.streak
        twin._heard = set(self._heard)
        return twin

    def _answer_again(self, bg: "LocalAgent") -> None:
        """The background window ``bg`` ends here unconverged: if the forms it holds now place an assembly its
        step's provisional answer left out (and place every one it placed), answer the step again with their joint
        solution (still provisional)."""
        bg.agent.settle_provisional()
        poses = bg.agent.estimates()
        if set(poses) > bg._answered:
            self._revisions.append(Revision(bg.step, dict(poses), bg.agent.unplaced(poses), bg.rounds,
                                            reason="more_forms", converged=False))

    def take_revisions(self) -> list[Revision]:
        """Steps answered provisionally whose window has since converged in the background, and steps answered
        again without a member a later window excluded, in that order (and forget them)."""
        out, self._revisions = self._revisions, []
        out += [Revision(step, poses, unplaced, 0, "excluded") for step, poses, unplaced in self.agent.take_revisions()]
        return out

    def receive(self, messages, round_index: int | None = None) -> None:
        """Handle messages arrived by round ``round_index``; ADMM values of a neighbour still at work wake a
        quiet agent. Messages of the background window's step (and configurations) go to it too; ADMM values of
        an older window than this one's never reach this one."""
        messages = list(messages)
        bg = self.background
        if bg is not None:
            bg.receive([m for m in messages if window_of(m) == bg.step or isinstance(m, ConfigAnnounce)],
                       round_index)
            if self._over:  # the last window went on in the background: its messages are its alone
                messages = [m for m in messages if window_of(m) != bg.step]
            messages = [m for m in messages if not (isinstance(m, (AdmmPrimal, AdmmDual)) and m.window < self.step)]
        self._receive(messages, round_index)

    def _receive(self, messages, round_index: int | None) -> None:
        if round_index is not None:
            self.agent.advance(round_index)
        for message in messages:
            if (self.done and isinstance(message, (AdmmPrimal, AdmmDual)) and "done" not in message.blocks
                    and message.window == self.step):
                self._heard.add(self.rounds)
            self.agent.handle(message)

    def half_round(self, round_index: int, phase: int) -> list[Message]:
        """Run phase ``phase`` of round ``round_index`` if there is work; return the messages to send."""
        if self.step is not None and not self.idle:
            self._ticked = True
            self.agent.tick(round_index, phase)
        if phase == 1 and self.step is not None:
            self._end_of_round()
        out = self.agent.outbox()
        bg = self.background
        if bg is not None:
            out += [m for m in bg.half_round(round_index, phase) if window_of(m) == bg.step]
            if bg.done and bg.converged and not bg._revised:
                bg._revised = True
                self._revisions.append(Revision(bg.step, dict(bg.window_estimate), dict(bg.window_unplaced),
                                                bg.rounds, without=tuple(getattr(bg.agent, "without", ()))))
        return out

    def _end_of_round(self) -> None:
        self.rounds += 1
        ticked, self._ticked = self._ticked, False
        if self.done:
            if ticked and not self.agent.converged and self.rounds < self.rule.budget:
                # answering moved it off its own convergence test: at work again (its values wake its neighbours)
                self.done = self.converged = False
                self.agent.window_done = False
                self.streak = 0
            return
        if self.rounds >= self.rule.min_rounds and self.agent.converged and self.agent.complete:
            self.streak += 1
        else:
            self.streak = 0
        if self.streak >= self.rule.settle:
            self._finish(converged=True)
        elif self.rounds >= self.rule.budget:
            self._finish(converged=False)

    def end_window(self) -> None:
        """The next sensor step is due: a window its rule has not ended yet ends here, unconverged. (A window that
        ended unconverged, here or by its budget, goes on in the background from the next step, where
        :attr:`WindowRule.background` allows; the background window of the step before ends for good then.)"""
        if self.step is not None and not self.done:
            self._finish(converged=False)

    def _finish(self, converged: bool) -> None:
        # an unconverged window answers from the forms that arrived (if the sharing has not ended) and goes on from
        # here once the next step has come, forked with that answer's joint solution (solved once, not again by the
        # fork unless more forms come); one that converged after all (an answer had made it busy again) needs no fork
        self._next_background = None
        if not converged:
            self.agent.settle_provisional()
            if self.rule.background and self.agent.windows_independent:
                self._next_background = self._fork()
        self.done = True
        self.converged = converged
        self.agent.window_done = True
        self.window_estimate = self.agent.estimates()
        self.window_unplaced = self.agent.unplaced(self.window_estimate)
        if self._next_background is not None:
            self._next_background._answered = frozenset(self.window_estimate)


class AgentHost:
    """Drives one :class:`LocalAgent` on a :class:`Transport`: the same calls in simulated and wall time."""

    def __init__(self, agent: LocalAgent, transport: Transport, on_send=None):
        self.agent = agent
        self.transport = transport
        self.on_send = on_send  # optional callback(message) for per-step counts

    def on_step(self, own: OwnStep, now: float, round_index: int) -> None:
        """Hand the agent a sensor step at round ``round_index`` and send what it announces."""
        self.agent.on_step(own, round_index)
        self._send(self.agent.agent.outbox(), now)

    def half_round(self, now: float, round_index: int, phase: int) -> None:
        """Deliver the agent's inbox at ``now``, run the half round, send its messages."""
        self.agent.receive((d.message for d in self.transport.poll(self.agent.name, now)), round_index)
        self._send(self.agent.half_round(round_index, phase), now)

    def _send(self, messages, now: float) -> None:
        for message in messages:
            self.transport.send(message, now)
            if self.on_send is not None:
                self.on_send(message)
