"""The local window rule and the quiet/answer behaviour of :class:`agents.runtime.LocalAgent`."""

import numpy as np
import pytest

from agents.assembly import OwnStep
from agents.runtime import LocalAgent, WindowRule
from decentral.errors import InputError
from protocols.messages import AdmmPrimal
from sims.runners.admm_run import AdmmRunConfig, run_admm
from sims.simulation.scenarios import get_scenario, simulate


class _Stub:
    """The agent surface a runtime uses, with a convergence flag the test sets."""

    def __init__(self, name="A0"):
        self.name = name
        self.converged = False
        self.complete = True  # its window holds every live agent's forms
        self.window_done = False
        self.ticks = []
        self.handled = []
        self.windows_independent = False  # (the background window has its own tests)
        self.revised = []  # (step, poses, unplaced) answered again without an excluded member
        self.answer = {"A1": "pose"}  # what it places (the test sets it)
        self.settled = 0  # times its answer was computed from the forms held

    def on_step(self, own, round_index=None):
        pass

    def advance(self, round_index):
        pass

    def handle(self, message):
        self.handled.append(message)

    def tick(self, round_index, phase=None):
        self.ticks.append((round_index, phase))

    def outbox(self):
        return []

    def estimates(self):
        return dict(self.answer)

    def unplaced(self, placed):
        return {}

    def settle_provisional(self):
        self.settled += 1

    def take_revisions(self):
        out, self.revised = self.revised, []
        return out


def _busy(round_index, done=False):
    blocks = {"x": np.zeros((1, 8)), "meta": np.zeros(4)}
    if done:
        blocks["done"] = np.ones(1)
    return AdmmPrimal(sender="A1", receiver="A0", round=round_index, window=0, blocks=blocks)


def _run_rounds(local, rounds, start=0, inbox=lambda r: ()):
    for r in range(start, start + rounds):
        for phase in (0, 1):
            local.receive(inbox(r) if phase == 0 else ())
            local.half_round(r, phase)


def test_a_window_that_never_converges_ends_at_the_round_budget_unconverged():
    """The budget between sensor steps ends a window whatever the convergence test says."""
    local = LocalAgent(_Stub(), WindowRule(budget=7))
    local.on_step(OwnStep(step=0, t=0.0, config={}))
    _run_rounds(local, 6)
    assert not local.done
    _run_rounds(local, 1, start=6)
    assert local.done and not local.converged and local.quiet


def test_the_convergence_flag_must_hold_for_settle_rounds():
    """Done only after the agent's own flag held `settle` rounds in a row (after `min_rounds`)."""
    stub = _Stub()
    local = LocalAgent(stub, WindowRule(min_rounds=2, settle=3, budget=100))
    local.on_step(OwnStep(step=0, t=0.0, config={}))
    stub.converged = True
    _run_rounds(local, 3)  # the flag counts from the 2nd round on: rounds 2 and 3
    assert not local.done
    _run_rounds(local, 1, start=3)
    assert local.done and local.converged and stub.window_done


def test_a_done_agent_answers_a_busy_neighbour_but_not_one_that_finished_with_it():
    """Values without `done` in two of the last four rounds wake a quiet agent for whole rounds (a neighbour at
    work behind a lossy link); a single one (possibly its last) does not, nor do values marked done."""
    stub = _Stub()
    local = LocalAgent(stub, WindowRule(min_rounds=0, settle=1, budget=100))
    local.on_step(OwnStep(step=0, t=0.0, config={}))
    stub.converged = True
    _run_rounds(local, 1)
    assert local.quiet
    n = len(stub.ticks)
    _run_rounds(local, 5, start=1, inbox=lambda r: [_busy(r)] if r == 1 else ())  # a last value, then silence
    assert len(stub.ticks) == n and local.quiet
    # at work, every other value lost: the values of rounds 6 and 8 wake it for round 9
    _run_rounds(local, 3, start=6, inbox=lambda r: [_busy(r)] if r in (6, 8) else ())
    assert len(stub.ticks) == n
    _run_rounds(local, 1, start=9)
    assert stub.ticks[-2:] == [(9, 0), (9, 1)]
    _run_rounds(local, 5, start=10, inbox=lambda r: [_busy(r, done=True)])  # values marked done: no answers
    assert local.quiet and stub.ticks[-1] == (10, 1)  # (round 10 still answers the values of rounds 6 and 8)


def test_the_next_step_ends_the_window_and_takes_the_estimate_held_then():
    """A step's estimate is what the agent holds when the next step comes."""
    local = LocalAgent(_Stub(), WindowRule(budget=50))
    local.on_step(OwnStep(step=0, t=0.0, config={}))
    _run_rounds(local, 3)
    local.end_window()
    assert local.window_estimate == {"A1": "pose"} and local.done and not local.converged


def test_the_rule_refuses_a_zero_budget():
    """A window needs at least one round."""
    with pytest.raises(InputError):
        WindowRule(budget=0)


def test_quiet_agents_send_nothing_until_the_next_step():
    """Running each step's whole round budget changes neither the estimates nor a single message count."""
    sim = simulate(get_scenario("multi", n_assemblies=4, steps=3), seed=1)
    fast = run_admm(sim.log, config=AdmmRunConfig(max_rounds=40), seed=0)
    full = run_admm(sim.log, config=AdmmRunConfig(max_rounds=40, fast_forward=False), seed=0)
    assert all(fast.converged) and max(fast.rounds) < 20 and full.rounds == (40, 40, 40)
    assert full.stats["messages"]["total"] == fast.stats["messages"]["total"]
    assert full.messages_per_step == fast.messages_per_step
    for a, b in zip(fast.estimate.steps, full.estimate.steps):
        assert a.poses.keys() == b.poses.keys()
        for name in a.poses:
            assert np.allclose(a.poses[name].p, b.poses[name].p, atol=1e-12)


class _Forking(_Stub):
    """A stub whose windows are independent (every window shares its forms): an unfinished one can be forked."""

    def __init__(self, name="A0"):
        super().__init__(name)
        self.windows_independent = True

    def fork(self):
        twin = _Forking(self.name)
        twin.converged, twin.answer = self.converged, dict(self.answer)
        return twin


def test_steps_the_agent_answered_again_without_an_excluded_member_are_revisions_taken_once():
    """What the agent answered again (a later window excluded a member) comes out as revisions of those steps,
    reason "excluded", once."""
    local = LocalAgent(_Stub())
    local.on_step(OwnStep(step=0, t=0.0, config={}))
    local.agent.revised = [(0, {"A1": "again"}, {"A2": "unobserved"})]
    revisions = local.take_revisions()
    assert [(r.step, r.poses, r.unplaced, r.reason) for r in revisions] == [(0, {"A1": "again"}, {"A2": "unobserved"},
                                                                             "excluded")]
    assert local.take_revisions() == []


def test_an_unconverged_window_goes_on_in_the_background_and_revises_its_step():
    """A window ended unconverged by its budget goes on beside the next one; once the fork converges its answer is a
    revision of that step, taken once."""
    local = LocalAgent(_Forking(), WindowRule(budget=4))
    local.on_step(OwnStep(step=0, t=0.0, config={}))
    _run_rounds(local, 4)
    assert local.done and not local.converged
    local.on_step(OwnStep(step=1, t=0.1, config={}), 4)
    background = local.background
    assert background is not None and background.step == 0
    background.agent.converged = True
    _run_rounds(local, 4, start=4)
    revisions = local.take_revisions()
    assert [r.step for r in revisions] == [0] and revisions[0].poses == {"A1": "pose"}
    assert local.take_revisions() == []
    local.on_step(OwnStep(step=2, t=0.2, config={}), 8)
    assert local.background is None or local.background.step == 1  # the step-0 window ended for good


def _background_of_step_0(answer_later):
    """A step-0 window ended unconverged, its fork at work beside step 1 until it places ``answer_later``; then
    step 2 comes (the fork ends unconverged). Returns the revisions taken."""
    local = LocalAgent(_Forking(), WindowRule(budget=4))
    local.on_step(OwnStep(step=0, t=0.0, config={}))
    _run_rounds(local, 4)
    local.on_step(OwnStep(step=1, t=0.1, config={}), 4)
    local.background.agent.answer = answer_later  # forms that came after the step's first answer
    _run_rounds(local, 4, start=4)
    assert local.take_revisions() == []  # not converged: nothing yet
    fork = local.background.agent
    local.on_step(OwnStep(step=2, t=0.2, config={}), 8)
    assert fork.settled  # the fork's answer was computed again from the forms it held at the end
    return local.take_revisions()


def test_a_background_window_that_ends_unconverged_answers_again_when_its_forms_place_more():
    """A fork that never converges, but whose forms place an assembly the first answer left out (and every one it
    placed), answers its step again at its end: reason "more_forms", unconverged, one step late."""
    revisions = _background_of_step_0({"A1": "better", "A2": "pose"})
    assert [(r.step, r.reason, r.converged, r.poses) for r in revisions] == [
        (0, "more_forms", False, {"A1": "better", "A2": "pose"})]


@pytest.mark.parametrize("later", [{"A1": "moved"}, {"A2": "pose"}, {}])
def test_a_background_window_that_places_no_more_leaves_the_first_answer(later):
    """Unconverged at its end, a fork that places the same assemblies, a different set or none does not answer its
    step again (a provisional answer is replaced only by one that places strictly more)."""
    assert _background_of_step_0(later) == []


def test_the_last_window_goes_on_in_the_background_after_the_log_ends():
    """The log's last window, unconverged when its next step would be due, goes on in the background like every
    other: its converged answer is a revision of the last step; the messages of that window reach the fork alone,
    and the step before's background window ends there (answered again: its forms place more)."""
    local = LocalAgent(_Forking(), WindowRule(budget=4))
    local.on_step(OwnStep(step=0, t=0.0, config={}))
    _run_rounds(local, 4)
    local.on_step(OwnStep(step=1, t=0.1, config={}), 4)
    local.background.agent.answer = {"A1": "pose", "A2": "late"}  # step 0's fork got more forms, never converged
    _run_rounds(local, 4, start=4)
    local.end_of_log()
    assert [(r.step, r.reason) for r in local.take_revisions()] == [(0, "more_forms")]
    tail = local.background
    assert tail is not None and tail.step == 1 and local.waiting_in_background
    own_before = len(local.agent.handled)
    tail.agent.converged = True
    _run_rounds(local, 4, start=8,
                inbox=lambda r: [AdmmPrimal(sender="A1", receiver="A0", round=r, window=1, blocks={"x": np.zeros((1, 8))})])
    assert len(local.agent.handled) == own_before and len(tail.agent.handled) == 4
    revisions = local.take_revisions()
    assert [(r.step, r.reason, r.converged) for r in revisions] == [(1, "background", True)]
    assert not local.waiting_in_background
    local.end_background()
    assert local.take_revisions() == []


def test_the_last_window_still_unconverged_at_the_end_answers_again_only_if_it_places_more():
    """The last window's background window ends with the run: unconverged, it answers again (still provisional)
    when its forms place more than the first answer, and not otherwise."""
    for later, expect in (({"A1": "pose", "A2": "late"}, [(1, "more_forms", False)]), ({"A1": "moved"}, [])):
        local = LocalAgent(_Forking(), WindowRule(budget=4))
        local.on_step(OwnStep(step=0, t=0.0, config={}))
        local.agent.converged = True
        _run_rounds(local, 4)
        local.agent.converged = False
        local.on_step(OwnStep(step=1, t=0.1, config={}), 4)
        _run_rounds(local, 4, start=4)
        local.end_of_log()
        local.background.agent.answer = later
        _run_rounds(local, 4, start=8)
        local.end_background()
        assert [(r.step, r.reason, r.converged) for r in local.take_revisions()] == expect
        assert not local.waiting_in_background


def test_a_window_that_converged_leaves_nothing_in_the_background():
    """A window that converged before the next step is not forked."""
    stub = _Forking()
    local = LocalAgent(stub, WindowRule(budget=50))
    local.on_step(OwnStep(step=0, t=0.0, config={}))
    stub.converged = True
    _run_rounds(local, 6)
    assert local.done and local.converged
    local.on_step(OwnStep(step=1, t=0.1, config={}), 6)
    assert local.background is None


def test_messages_are_routed_by_the_window_they_belong_to():
    """ADMM values name their window, form messages their step; heartbeats and configurations belong to none."""
    from agents.runtime import window_of
    from protocols.messages import Heartbeat

    assert window_of(_busy(3)) == 0
    assert window_of(Heartbeat(sender="A1", receiver="A0", round=2, t=0.0)) is None
