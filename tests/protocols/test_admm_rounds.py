"""The ADMM rounds of one agent (protocols.admm_rounds), driven by hand-built views and messages.

A1 observes A0 (the reference) 1 m ahead at step 0; A1's rounds run against a hand-fed inbox.
"""

import numpy as np

from decentral.admm import AdmmConfig, ConsensusState, PairState, quadratic_form
from decentral.geometry import rot2
from protocols.admm_rounds import AdmmRounds, RoundView
from protocols.admm_values import AdmmInbox, value_blocks
from protocols.messages import AdmmDual, AdmmPrimal
from protocols.pose_gossip import PoseGossip

Q = np.array([[0.1, 0.0, 0.0], [0.0, 0.1, 0.05], [-0.1, 0.05, 0.0]])
PATIENCE = 3


class _Agent:
    """A1's window: one pair (A1 -> A0), its consensus, inbox and gossip table, and its ADMM rounds."""

    def __init__(self, pairs=True, name="A1", pinned=False):
        cfg = AdmmConfig()
        self.consensus = ConsensusState(name, pinned)
        self.consensus.slide([0], {})
        self.pairs = {}
        if pairs:
            pair = PairState(name, "A0", cfg)
            pair.set_problem(quadratic_form([(name, 0), ("A0", 0)], visual=(
                np.zeros(3, int), np.ones(3, int), Q, Q + np.array([1.0, 0, 0]), np.ones(3))))
            self.pairs["A0"] = pair
        self.inbox = AdmmInbox()
        self.gossip = PoseGossip(1, 2, 1e-4, 10)
        self.counters = {"timeouts": 0, "retransmits": 0, "uncertified": 0}
        self.rounds = AdmmRounds(name, 1, cfg, patience=PATIENCE, window=5, share_timeout=20, counters=self.counters)
        self.round = 0

    def view(self, **kw):
        args = dict(round=self.round, step=0, pairs=self.pairs, consensus=self.consensus, inbox=self.inbox,
                    gossip=self.gossip, seeds={}, seeds_complete=False, forms_current=True, expected=frozenset(),
                    pair_steps=frozenset({0} if self.pairs else ()), unresolved=False)
        args.update(kw)
        return RoundView(**args)

    def primal_from_target(self, iteration):
        """A0's consensus (at the origin, pinned and ready) of ``iteration``, arriving this round."""
        self.inbox.receive(AdmmPrimal(sender="A0", receiver="A1", round=self.round, window=0,
                                      blocks=value_blocks([(0, (rot2(0.0), np.zeros(3)))], True, iteration)))


def test_a_pair_iterates_then_waits_for_the_targets_next_consensus_resending_its_dual():
    """Iteration 1 goes out at once; without A0's consensus of it the same dual is resent (counted), not recomputed."""
    a = _Agent()
    first = a.rounds.pair_phase(a.view())
    assert [(type(m), m.receiver) for m in first] == [(AdmmDual, "A0")] and first[0].blocks["meta"][3] == 1
    a.round = 1
    again = a.rounds.pair_phase(a.view())
    assert len(again) == 1 and np.array_equal(again[0].blocks["x"], first[0].blocks["x"])
    assert a.counters["retransmits"] == 1 and a.pairs["A0"].iterations == 1


def test_a_silent_target_is_not_waited_for_longer_than_patience():
    """After `patience` rounds without the target's consensus the pair iterates anyway: a timeout."""
    a = _Agent()
    a.rounds.pair_phase(a.view())
    for r in range(1, PATIENCE + 2):
        a.round = r
        a.rounds.pair_phase(a.view())
    assert a.counters["timeouts"] == 1 and a.pairs["A0"].iterations == 2


def test_the_consensus_updates_once_per_pair_iteration_and_waits_for_the_next():
    """The consensus updates with the pair's copies of iteration 1, then waits (resending) until iteration 2 is in."""
    a = _Agent()
    a.primal_from_target(0)
    a.rounds.pair_phase(a.view())
    a.rounds.consensus_phase(a.view())
    assert len(a.consensus.changes) == 1 and a.counters["retransmits"] == 0
    a.round = 1
    a.rounds.consensus_phase(a.view())
    assert len(a.consensus.changes) == 1 and a.counters["retransmits"] == 1
    a.primal_from_target(1)
    a.rounds.pair_phase(a.view())
    a.rounds.consensus_phase(a.view())
    assert len(a.consensus.changes) == 2 and a.counters["timeouts"] == 0


def test_observers_get_the_consensus_as_primal_unless_gone_for_long():
    """Every observer heard lately gets admm.primal; one silent for window + 2 patience + 10 rounds does not."""
    a = _Agent(pairs=False, name="A1", pinned=True)
    a.inbox.receive(AdmmDual(sender="A2", receiver="A1", round=0, window=0,
                             blocks=value_blocks([(0, (rot2(0.0), np.array([1.0, 0, 0])))], True, 1, rho=(1.0, 1.0))))
    out = a.rounds.consensus_phase(a.view())
    assert [(type(m), m.receiver) for m in out] == [(AdmmPrimal, "A2")]
    a.round = 5 + 2 * PATIENCE + 10 + 1
    assert a.rounds.consensus_phase(a.view()) == []


def test_an_agent_with_nobody_to_agree_with_converges_after_patience_rounds_unless_nodes_are_unnamed():
    """No pairs, no observers: converged after `patience` consensus phases, never while nodes are unnamed."""
    a = _Agent(pairs=False, pinned=True)
    flags = []
    for r in range(PATIENCE + 1):
        a.round = r
        a.rounds.consensus_phase(a.view())
        flags.append(a.rounds.converged)
    assert flags == [False] * (PATIENCE - 1) + [True, True]
    b = _Agent(pairs=False, pinned=True)
    for r in range(PATIENCE + 3):
        b.round = r
        b.rounds.consensus_phase(b.view(unresolved=True))
    assert not b.rounds.converged
    a.rounds.new_window()
    assert not a.rounds.converged


def test_a_seeded_start_waits_for_an_expected_observer_share_timeout_rounds():
    """With every agent's forms, a missing expected observer holds the consensus for share_timeout rounds, else patience."""
    for complete, wait in ((True, 20), (False, PATIENCE)):
        a = _Agent(pairs=False)
        updates = []
        for r in range(wait + 2):
            a.round = r
            before = a.counters["timeouts"]
            a.rounds.consensus_phase(a.view(expected=frozenset({"A2"}), seeds_complete=complete))
            updates.append(a.counters["timeouts"] > before)
        assert updates.index(True) == wait, complete


def test_values_carry_done_tree_and_gossip_blocks_as_the_view_says():
    """A window the runtime ended adds `done`; a tree place adds `tree` (hop, parent); without it no `tree`."""
    a = _Agent()
    plain = a.rounds.pair_phase(a.view())[0].blocks
    assert "done" not in plain and "tree" not in plain
    a.round = 1
    marked = a.rounds.pair_phase(a.view(done=True, place=(2, -1)))[0].blocks
    assert np.array_equal(marked["done"], [1.0]) and np.array_equal(marked["tree"], [2.0, -1.0])


def test_a_restart_forgets_the_iterations_of_the_old_window():
    """After restart() the pair phase starts again at iteration 1, and forget() drops a pair's last dual."""
    a = _Agent()
    a.rounds.pair_phase(a.view())
    a.primal_from_target(1)
    a.rounds.consensus_phase(a.view())
    a.round = 1
    assert a.rounds.pair_phase(a.view())[0].blocks["meta"][3] == 2
    a.rounds.restart()
    a.inbox.keep_from(1)
    a.round = 2
    assert a.rounds.pair_phase(a.view())[0].blocks["meta"][3] == 1
    a.rounds.forget("A0")
    a.round = 3
    a.rounds.pair_phase(a.view(pairs={}))
    assert a.rounds.pair_phase(a.view())[0].blocks["meta"][3] == 1  # nothing kept: iterates afresh
