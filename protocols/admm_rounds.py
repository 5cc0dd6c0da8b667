"""The consensus-ADMM rounds of one assembly agent: the pair phase and the consensus phase.

The role the assembly agent (:mod:`agents.assembly`) plays once a window's forms are shared (the
agent's module docstring describes the protocol). Each ADMM round has two halves:

* **pair phase** (:meth:`AdmmRounds.pair_phase`): every pair the agent owns iterates once the target's
  consensus of the pair's iteration has arrived (or after ``patience`` rounds of waiting), and sends
  the target its ``copy + dual`` as ``admm.dual`` (its last one again while waiting: that repairs a
  lost copy);
* **consensus phase** (:meth:`AdmmRounds.consensus_phase`): the agent's consensus poses are updated
  once every pair's copies of the next iteration are in (own pairs, and the ``admm.dual`` of the
  observers), sent to the observers as ``admm.primal``, and the convergence flag is set.

Lost, late, duplicated or reordered messages: every value carries its ADMM iteration number. A pair
iterates only when both ends' consensus of the current iteration is in, and a consensus update only
when every pair's copies of the next iteration are in; meanwhile the agent resends its last value
each round (which repairs a lost copy), so losses mostly delay the iterates rather than change them
(they still change when a neighbour's first message or a configuration arrives late, or on a
timeout). A neighbour silent for ``patience`` rounds (crashed, partitioned, or no longer
watching) is not waited for: its newest value is reused with its age, counted as a timeout. Older
rounds never overwrite newer values (reordering, duplicates), and a restarted agent jumps its
iteration counter forward to its neighbours'. Ages in rounds are kept (:attr:`AdmmRounds.ages`).

Message counts per round and agent: one ``admm.dual`` per observed assembly and one ``admm.primal``
per observer, i.e. the agent's degree in the view graph.

Every input of a half round is explicit: a :class:`RoundView` of the window the agent works on (its
pairs, consensus and inbox, the known joint solution, the round). The numerical steps are
:class:`decentral.admm.PairState` and :class:`decentral.admm.ConsensusState`; this module decides
when they run, what goes out, and when the agent may say it has converged.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

from decentral.admm import AdmmConfig, ConsensusState, PairState
from decentral.geometry import wrap_angle
from protocols.admm_values import AdmmInbox, packed_metric, value_blocks
from protocols.messages import AdmmDual, AdmmPrimal
from protocols.pose_gossip import PoseGossip, pose_row

__all__ = ["RoundView", "AdmmRounds"]

_DONE = np.ones(1)
_NEVER_DUE = 10**12  # the iteration of an observer no longer waited for


@dataclass(frozen=True)
class RoundView:
    """What a half round works on: the agent's window as it is at this round.

    Attributes
    ----------
    round : int
        The round under way.
    step : int
        The window's newest log step.
    pairs : Mapping[str, PairState]
        Target -> the agent's pair subproblem (updated in place by the pair phase).
    consensus : ConsensusState
        The agent's consensus poses (updated in place by the consensus phase).
    inbox : AdmmInbox
        The newest ADMM values of every target and observer.
    gossip : PoseGossip
        The gossip table (the consensus phase writes the agent's own row; both phases attach it).
    seeds : Mapping
        ``(assembly, step) -> (R (2, 2), p (3,))`` of the window's known joint solution (may be empty).
    seeds_complete : bool
        The seeds come from every live agent's forms.
    forms_current : bool
        The agent's pairs are the ones its shared forms described (none built or grown since).
    expected : frozenset of str
        Observers whose first values a seeded start waits for.
    pair_steps : frozenset of int
        Steps of the window with own visual factors.
    unresolved : bool
        Nodes are seen that no known configuration names yet (a pair may still be missing).
    done : bool
        The runtime has ended the agent's window (its values then carry a ``done`` block).
    place : tuple of int or None
        ``(hop, parent)`` in the aggregation tree, -1 for none, sent as the ``tree`` block (None: no tree).
    """

    round: int
    step: int
    pairs: Mapping[str, PairState]
    consensus: ConsensusState
    inbox: AdmmInbox
    gossip: PoseGossip
    seeds: Mapping
    seeds_complete: bool
    forms_current: bool
    expected: frozenset
    pair_steps: frozenset
    unresolved: bool
    done: bool = False
    place: tuple | None = None


class AdmmRounds:
    """One agent's ADMM iteration counters, last values sent, waiting counts and convergence flag.

    Parameters
    ----------
    name : str
        The agent's assembly.
    me : int
        Its index (its row in the gossip table).
    admm : AdmmConfig
        Tolerances (``eps_rot``, ``eps_pos``, ``tail``).
    patience : int
        Rounds a half round waits for a neighbour's value of the current iteration.
    window : int
        Sliding-window length (an observer silent for ``window + 2 patience + 10`` rounds is gone).
    share_timeout : int
        Rounds a seeded start with every agent's forms waits for an expected observer.
    counters : dict
        The agent's counters (``timeouts``, ``retransmits``, ``uncertified`` are counted here).

    Attributes
    ----------
    converged : bool
        The last completed iteration met the convergence test (kept while waiting for the next).
    ages : dict
        Rounds since the newest value used from each neighbour, at the last consensus phase.
    """

    def __init__(self, name: str, me: int, admm: AdmmConfig, *, patience: int, window: int, share_timeout: int,
                 counters: dict):
        self.name, self.me, self.admm = name, me, admm
        self.patience, self.window, self.share_timeout = patience, window, share_timeout
        self.counters = counters
        self.converged = False
        self.ages: dict[str, int] = {}
        self._iter = 0  # consensus iterations done
        self._iter_before = 0
        self._step_rounds = 0  # consensus phases in this window
        self._fresh_pairs = True
        self._pair_iter: dict[str, int] = {}
        self._pair_out: dict[str, tuple] = {}  # target -> (own copies, metrics, usable, iteration)
        self._waiting: dict[tuple, int] = {}
        self._last_dual: dict[str, dict] = {}
        self._last_primal: dict | None = None

    def new_window(self) -> None:
        """A new log step: not converged, no consensus phase run yet."""
        self.converged = False
        self._step_rounds = 0

    def restart(self) -> None:
        """A fresh start at the window's fixed point: earlier iterations and values belong to the old window."""
        self._iter = 0
        self._pair_iter, self._waiting, self._pair_out, self._last_dual = {}, {}, {}, {}
        self._last_primal = None

    def forget(self, target: str) -> None:
        """The pair with ``target`` is gone (no detections of it left in the window)."""
        for store in (self._pair_out, self._last_dual, self._pair_iter):
            store.pop(target, None)

    # ------------------------------------------------------------------ phase 0
    def pair_phase(self, view: RoundView) -> list[AdmmDual]:
        """Phase 0: each owned pair iterates once the target's consensus of its iteration has arrived; the
        ``admm.dual`` to every target (a new value, or the last one again)."""
        me, cons, patience = self.name, view.consensus, self.patience
        out = []
        self._fresh_pairs = True
        for target, pair in view.pairs.items():
            inbound = view.inbox.targets.get(target)
            i = self._pair_iter.get(target, 0)
            waited = self._waiting.get(("pair", target), 0)
            # not heard from for `patience` rounds: gone (crashed, cut off, or no longer watching) - go on
            # iteration i + 1 uses both ends' consensus of iteration i (Boyd §7.1's synchronous order)
            fresh = ((inbound is None or inbound.iteration >= i or view.inbox.age(inbound, view.round) > patience)
                     and self._iter >= i)
            due = fresh or waited >= patience
            if due:
                if not fresh:
                    self.counters["timeouts"] += 1  # go on with the newest (stale) values
                    self._fresh_pairs = False
                z = {(me, k): v for k, v in cons.z.items()}
                ready = {me: cons.ready, target: False}
                if inbound is not None:
                    z.update({(target, k): v for k, v in inbound.values.items() if k in cons.z})
                    ready[target] = inbound.ready
                elif any(key[0] == target for key in view.seeds):  # nothing heard yet: the seeded solution
                    z.update({key: v for key, v in view.seeds.items() if key[0] == target and key[1] in cons.z})
                    ready[target] = True
                values, metrics = pair.iterate(z, ready)
                if not pair.certified:
                    self.counters["uncertified"] += 1
                i = max(i, inbound.iteration if inbound is not None else 0) + 1
                self._pair_iter[target] = i
                self._waiting[("pair", target)] = 0
                mine = {k[1]: v for k, v in values.items() if k[0] == me}
                mine_m = {k[1]: v for k, v in metrics.items() if k[0] == me}
                self._pair_out[target] = (mine, mine_m, cons.ready or ready[target], i)
                theirs = sorted((k[1], v) for k, v in values.items() if k[0] == target)
                w = np.array([packed_metric(metrics[(target, k)]) for k, _ in theirs], float).reshape(-1, 7)
                self._last_dual[target] = value_blocks(theirs, cons.ready, i, rho=(pair.rho_R, pair.rho_p), w=w)
            else:
                self._waiting[("pair", target)] = waited + 1
                self.counters["retransmits"] += 1
            if target in self._last_dual:  # a new value, or the last one again (repairs a lost copy)
                out.append(AdmmDual(sender=me, receiver=target, round=view.round, window=view.step,
                                    rho=float(self._last_dual[target]["meta"][1]) or 1.0,
                                    blocks=self._with_table(view, self._last_dual[target], target)))
        return out

    # ------------------------------------------------------------------ phase 1
    def consensus_phase(self, view: RoundView) -> list[AdmmPrimal]:
        """Phase 1: the consensus update once every pair's copies of the next iteration are in; the
        ``admm.primal`` to every observer not gone; the convergence flag."""
        cons = view.consensus
        self._step_rounds += 1
        gone = self.window + 2 * self.patience + 10
        ages, inputs = {}, []
        for target in view.pairs:
            ages[target] = view.inbox.age(view.inbox.targets.get(target), view.round)
            if target in self._pair_out:
                mine, mine_m, usable, it = self._pair_out[target]
                inputs.append((it, usable, (mine, mine_m)))
        for sender, inbound in view.inbox.observers.items():
            age = view.inbox.age(inbound, view.round)
            if age > gone:
                continue  # an observer gone for long: its copies no longer count
            ages[sender] = age
            if not any(k in cons.z for k in inbound.values):
                continue  # copies of steps that left the window
            # an observer silent for `patience` rounds is not waited for (its newest copies still count)
            it = inbound.iteration if age <= self.patience else _NEVER_DUE
            inputs.append((it, inbound.ready or cons.ready, (inbound.values, inbound.metrics)))
        self.ages = ages
        waited = self._waiting.get(("cons", ""), 0)
        lowest = min((it for it, _, _ in inputs), default=self._iter + 1)
        patience = self.patience
        if any(a not in view.inbox.observers for a in view.expected):
            lowest = -1  # a seeded start without an observer's contribution would leave the fixed point
            if view.seeds_complete:
                # the observer is most likely still getting the window's forms (late under loss): leaving the
                # exact fixed point without it cost 100-250 rounds per window at 50 % loss; wait longer
                patience = self.share_timeout
        self._iter_before = self._iter
        due = lowest >= self._iter + 1 or waited >= patience or cons.pinned and not inputs
        if due:
            if lowest < self._iter + 1:
                self.counters["timeouts"] += 1
            cons.update([c for _, usable, c in inputs if usable])
            self._iter = max([self._iter + 1] + [it for it, _, _ in inputs if it < _NEVER_DUE])
            self._waiting[("cons", "")] = 0
            last = view.step
            if cons.ready and cons.anchored(last, set(view.pair_steps) | view.inbox.remote_steps()):
                R, p = cons.z[last]
                view.gossip.set_own(pose_row(self.me, last, view.round, R, p), view.round)
            self._last_primal = value_blocks(sorted(cons.z.items()), cons.ready, self._iter)
        else:
            self._waiting[("cons", "")] = waited + 1
            self.counters["retransmits"] += 1
        out = []
        if self._last_primal is not None:
            for observer in view.inbox.observers:
                if ages.get(observer, gone + 1) <= gone:
                    out.append(AdmmPrimal(sender=self.name, receiver=observer, round=view.round, window=view.step,
                                          blocks=self._with_table(view, self._last_primal, observer)))
        if due:  # the flag describes the last completed iteration (kept while waiting for the next)
            eps = self.admm
            # nobody to agree with after `patience` rounds of this step and no unnamed detections:
            # nothing left to do (counting it converged earlier ended lossy steps before discovery)
            alone = not view.pairs and not inputs and not view.unresolved and self._step_rounds >= self.patience
            self.converged = alone or bool(
                lowest >= self._iter_before + 1
                and view.gossip.settled(view.round)  # the gossip of the others' poses has settled
                and cons.ready
                and all(p.converged() for p in view.pairs.values())
                and cons.change <= max(eps.eps_rot, eps.eps_pos)
                and (cons.remaining() <= eps.tail * max(eps.eps_rot, eps.eps_pos) or self._near_seeds(view))
                and self._fresh_pairs
                # nodes it sees but cannot name yet (lost announcements): their pair is still to come
                and not view.unresolved
            )
        return out

    def _near_seeds(self, view: RoundView) -> bool:
        """With every agent's forms, the window started at the joint solution (the fixed point): the
        consensus staying within the ADMM tolerances of it is convergence, whatever the tail estimate
        (which, on changes at the solver's precision, ~1e-7, can predict a long way still to go)."""
        if not view.seeds_complete or not view.forms_current:
            return False  # (a pair built or grown after the forms went out: the joint solution lacks it)
        eps = self.admm
        for k, (R, p) in view.consensus.z.items():
            seed = view.seeds.get((self.name, k))
            if seed is None:
                return False
            R0, p0 = seed
            dyaw = abs(wrap_angle(np.arctan2(R[1, 0], R[0, 0]) - np.arctan2(R0[1, 0], R0[0, 0])))
            if dyaw > eps.eps_rot or np.abs(p - p0).max() > eps.eps_pos:
                return False
        return True

    @staticmethod
    def _with_table(view: RoundView, blocks: dict, receiver: str) -> dict:
        """``blocks`` plus ``done`` once the window is done, the sender's place in the aggregation tree
        (``tree``: hop to the reference, parent; -1 for none) and the gossip table if it changed since it
        last went to ``receiver`` (or is due)."""
        if view.done:
            blocks = dict(blocks, done=_DONE)
        if view.place is not None:
            blocks = dict(blocks, tree=np.array(view.place, float))
        table = view.gossip.attach(receiver, view.round)
        return blocks if table is None else dict(blocks, table=table)
