"""One window's sharing of the cost forms at one agent, as typed state (:mod:`protocols.window_aggregation`).

:class:`WindowShare` holds a window's records (every agent's forms seen here, in a
:class:`protocols.aggregation.TreeAggregation`), how they travel, the timers of the sharing, and the
window's joint solution (:func:`decentral.admm.solve_joint`, computed once) with its placement test;
:class:`DownState` the final set as sent down; :class:`OwnForms` the agent's own forms as shared. The
window's wire messages (its bundles, acknowledgement and joint solution) are packed here.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from decentral.admm import LocalProblem, solve_joint
from decentral.consistency import screen_members, without_members

#: windows of at most this many members are screened for a member whose data the others contradict (the
#: tests cost about 14 joint solves a window: 22 ms for 12 members, 46 ms for 16, one core; larger windows are
#: solved as they come). ``benchmarks/screening.py``
SCREEN_MAX_MEMBERS = 16
from decentral.geometry import rot2
from decentral.unplaced import unplaced_reasons
from protocols.admm_messages import FormAck, FormBundle, pack_bundle
from protocols.aggregation import DownRepair, TreeAggregation
from protocols.delta_messages import JointPoses
from protocols.messages import BROADCAST

__all__ = ["NEVER", "OwnForms", "WindowShare", "DownState"]

#: a round long before any other (nothing sent or asked yet)
NEVER = -(10**9)


class _Unsolved:
    """The joint solution of a window not solved yet: one instance, kept by copies (an agent's window is forked)."""

    def __copy__(self):
        return self

    def __deepcopy__(self, memo):
        return self


_UNSOLVED = _Unsolved()


@dataclass(frozen=True)
class OwnForms:
    """The forms an agent shared for window ``step``: packed ``keys`` (n, 4) int and ``forms``, the gauge
    ``pin`` (``(step, x, y, z, theta)`` at the reference, else empty), and the same forms as a record
    ``[(keys, LocalProblem)]`` (what a compact broadcast digests)."""

    step: int
    keys: np.ndarray
    forms: np.ndarray
    pin: np.ndarray
    record: tuple = ()


@dataclass
class WindowShare:
    """One window's sharing of the cost forms at one agent.

    Attributes
    ----------
    step : int
        The window's log step.
    agg : TreeAggregation
        Its records (agent index -> ``[(keys, LocalProblem)]``) and the tree's bookkeeping.
    mode : {"tree", "broadcast"} or None
        How the forms travel (None until the agent's own forms are shared).
    start : int or None
        Round of the first bootstrap phase of the window.
    sent : int
        Round of the last broadcast of the own forms.
    waited : int
        Bootstrap phases run.
    pin : ndarray or None
        The reference's gauge value ``(step, x, y, z, theta)`` of the window, when received.
    start_at : int
        Round at which the ADMM starts (from the down bundle; 0: at once).
    asked_at : int
        Round this agent last asked a neighbour for the final set (:meth:`WindowAggregation.ask`).
    asked, last : int
        After a timeout: how often, and at which round last, the parent was asked for the down bundle.
    solution : JointPoses or None
        The reference's joint solution as it came down.
    solution_out : JointPoses or None
        At the reference: the joint solution it sends down.
    joint : JointSolution or None
        The joint solution of the records (once :meth:`solve` has run: ``solved``).
    placeable : frozenset or None
        ``(assembly, step)`` keys the joint placement test places, and ``yaw_std`` its yaw deviations.
    excluded : tuple
        Members whose data the others contradict, left out of the joint solution
        (:func:`decentral.consistency.screen_members`); ``kept`` the forms it was solved from; ``suspects``
        the members one of which contradicts the others when the test cannot say which (none excluded).
    """

    step: int
    agg: TreeAggregation
    mode: str | None = None
    start: int | None = None
    sent: int = NEVER
    waited: int = 0
    pin: np.ndarray | None = None
    start_at: int = 0
    asked_at: int = NEVER
    asked: int = 0
    last: int = 0
    solution: JointPoses | None = None
    solution_out: JointPoses | None = None
    joint: Any = _UNSOLVED
    solved_for: tuple | None = None  # the records and pin the joint solution was computed from
    placeable: frozenset | None = None
    yaw_std: Any = None
    excluded: tuple = ()
    suspects: tuple = ()
    kept: list | None = None

    @property
    def solved(self) -> bool:
        """Whether :meth:`solve` has run for this window's records as they are now (records that arrived since,
        or a new pin, make the joint solution stale: a window answered provisionally and completed later must
        not keep the partial set's solution)."""
        return self.joint is not _UNSOLVED and self.solved_for == self._held()

    def _held(self) -> tuple:
        pin = () if self.pin is None else tuple(np.asarray(self.pin, float).tolist())
        return tuple((i, len(self.records[i])) for i in sorted(self.records)), pin

    def solve(self, reference: str, first: int, classes: bool = True) -> bool:
        """Compute the joint solution of the forms held (:func:`decentral.admm.solve_joint`) with the gauge at
        ``(reference, first)``, the window's first step: ``joint`` is ``None`` without forms or without the
        gauge's value at this window (known at step 0, else from the reference's ``pin``); ``classes``: run the
        class-by-class lie tests too (:func:`decentral.consistency.screen_members`). ``False`` when the
        solve failed: a set whose variables are tied by keys but not by factors (a step with neither
        odometry nor detections, forms missing); the ADMM then goes on from its own state."""
        self.joint, self.solved_for, self.placeable = None, self._held(), None
        problems = self.problems()
        known, value = self._gauge(first)
        if problems and known:
            try:
                # a member whose data the others contradict is left out, with every form over its poses
                members = {k[0] for prob in problems for k in prob.keys}
                joint = None
                if len(members) <= SCREEN_MAX_MEMBERS:
                    screening = screen_members(problems, (reference, first), value, classes=classes)
                    self.excluded, self.kept = screening.excluded, screening.kept
                    self.suspects = tuple(screening.suspects)
                    joint = screening.solution  # (solved already when nobody was excluded)
                else:
                    self.excluded, self.kept = (), problems
                self.joint = joint if joint is not None else solve_joint(self.kept, (reference, first), value)
            except np.linalg.LinAlgError:
                return False
        return True

    def _gauge(self, first: int) -> tuple[bool, tuple | None]:
        """Whether the gauge's value at window start ``first`` is known here (at step 0, the identity; else from
        the reference's ``pin``), and that value ``(R, p)`` (None: the identity)."""
        pin = self.pin
        if pin is not None and int(pin[0]) == first:
            return True, (rot2(float(pin[4])), np.array(pin[1:4]))
        return first == 0, None

    def without(self, members, reference: str, first: int) -> "WindowShare | None":
        """This window solved again without every form over a pose of ``members`` (members a later window
        excluded): a copy whose ``kept``, ``excluded`` and ``joint`` say so (its placement computed afresh),
        gauge as in :meth:`solve`; None where :meth:`solve` kept nothing or the rest does not tie the
        gauge's variables."""
        known, value = self._gauge(first)
        if self.kept is None or not known:
            return None
        rest = without_members(self.kept, members)
        if not rest:
            return None
        try:
            joint = solve_joint(rest, (reference, first), value)
        except np.linalg.LinAlgError:
            return None
        again = copy.copy(self)
        again.kept, again.joint, again.solved_for = rest, joint, self._held()
        again.excluded = tuple(self.excluded) + tuple(sorted(members, key=repr))
        again.placeable = again.yaw_std = None
        return again

    def placeable_keys(self, joint, name: str, step: int, limit: float) -> frozenset:
        """``(assembly, step)`` keys the centralized placement test places on ``joint`` relative to ``name`` at
        ``step`` (Laplace yaw std at most ``limit``, rad); computed once per window."""
        if self.placeable is None:
            self.placeable, self.yaw_std = joint.placement((name, step), limit)
        return self.placeable

    def unplaced(self, joint, names, name: str, step: int, limit: float) -> dict[str, str]:
        """Why the joint placement test leaves an assembly out at ``step`` (assembly -> reason code of
        :func:`decentral.unplaced.unplaced_reasons`)."""
        placed = {a for a, _ in self.placeable_keys(joint, name, step, limit)}
        problems = self.kept if self.kept is not None else self.problems()
        return unplaced_reasons(
            names, name, placed,
            with_data={a for prob in problems if len({k[0] for k in prob.keys}) > 1 for a, _ in prob.keys},
            connected={a for a, k in joint.index if k == step}, solved=True, yaw_std=self.yaw_std)

    def bundle(self, sender: str, receiver: str, indices, *, down: bool, start: int, round_index: int,
               reference: int) -> FormBundle:
        """The records ``indices`` as an ``admm.bundle`` (with the gauge ``pin`` when the ``reference``'s
        record is among them); ``down``: the final set from the parent, ADMM from round ``start``."""
        agg = self.agg
        records = {i: [(keys, prob.M, prob.b_z, prob.c_z, prob.count) for keys, prob in agg.records[i]] for i in indices}
        members, owners, keys, flat = pack_bundle(records)
        pin = self.pin if self.pin is not None and reference in records else np.zeros(0)
        return FormBundle(sender=sender, receiver=receiver, round=round_index, step=self.step, down=down,
                          hop=agg.hop, parent=-1 if agg.parent is None else agg.parent, depth=agg.depth,
                          start=start, members=members, owners=owners, keys=keys, forms=flat, pin=pin)

    def ack(self, sender: str, receiver: str, round_index: int) -> FormAck:
        """The acknowledgement of a bundle: the records held here."""
        return FormAck(sender=sender, receiver=receiver, round=round_index, step=self.step,
                       have=np.array(sorted(self.agg.records), dtype=np.int64))

    def solution_message(self, sender: str, joint, index: Mapping[str, int], placeable: set[int],
                         edges: set | None, round_index: int, n: int) -> JointPoses:
        """The joint solution as it goes down (:class:`protocols.delta_messages.JointPoses`): the newest step's
        poses (float32 on the wire), the records it was solved from, the ``placeable`` agent indices and
        the view graph's ``edges`` (None: unchanged, sent as an empty mask); ``n`` agents."""
        step = self.step
        rows = sorted((index[a], p, float(np.arctan2(R[1, 0], R[0, 0])))
                      for (a, k), (R, p) in joint.poses.items() if k == step and a in index)
        return JointPoses(sender=sender, receiver=BROADCAST, round=round_index, step=step, hop=0, parent=-1,
                          depth=self.agg.depth, start=0, n=n, members=JointPoses.mask(self.records, n),
                          index=JointPoses.mask([r[0] for r in rows], n),
                          poses=np.array([[*r[1], r[2]] for r in rows], float).reshape(-1, 4),
                          placeable=JointPoses.mask(placeable, n),
                          edges=JointPoses.mask([a * n + b for a, b in edges], n * n) if edges is not None
                          else np.zeros(0, np.uint8))

    @property
    def records(self) -> dict:
        """Agent index -> its forms ``[(keys, LocalProblem)]`` held for the window."""
        return self.agg.records

    def problems(self) -> list[LocalProblem]:
        """Every form held, in agent order."""
        return [prob for idx in sorted(self.records) for _, prob in self.records[idx]]

    def edges(self) -> set[tuple[int, int]]:
        """The view graph's observing pairs ``(observer, target)`` the forms name (each pair form names its
        observer first and its target last)."""
        return {(keys[0][0], keys[-1][0]) for idx in self.records for keys, _ in self.records[idx]
                if keys[0][0] != keys[-1][0]}

    def observers_of(self, me: int) -> set[int]:
        """Agents whose pair forms observe agent ``me``."""
        return {keys[0][0] for idx in self.records for keys, _ in self.records[idx]
                if len(keys) >= 2 and keys[1][0] == me and keys[0][0] != me}


@dataclass
class DownState:
    """The final set of a window as this agent sent it down (kept to answer children that lack it).

    Attributes
    ----------
    share : WindowShare
        The window it belongs to.
    start : int
        The round at which the ADMM starts, as sent.
    repair : DownRepair
        Children that may still lack it.
    bundle : FormBundle or None
        The packed forms (packed when first needed).
    """

    share: WindowShare
    start: int
    repair: DownRepair
    bundle: FormBundle | None = None

    @property
    def step(self) -> int:
        return self.share.step

    def to(self, sender: str, receiver: str, round_index: int, solution: JointPoses | None,
           reference: int) -> FormBundle | JointPoses:
        """The down message for ``receiver``: the joint ``solution`` when there is one, else the final set's
        forms (packed once)."""
        share = self.share
        if solution is not None:
            agg = share.agg
            return JointPoses(sender=sender, receiver=receiver, round=round_index, step=solution.step,
                              hop=agg.hop, parent=-1 if agg.parent is None else agg.parent, depth=solution.depth,
                              start=self.start, n=solution.n, members=solution.members, index=solution.index,
                              poses=solution.poses, placeable=solution.placeable, edges=solution.edges)
        if self.bundle is None:
            self.bundle = share.bundle(sender, BROADCAST, sorted(share.records), down=True, start=self.start,
                                       round_index=round_index, reference=reference)
        b = self.bundle
        return FormBundle(sender=sender, receiver=receiver, round=round_index, step=b.step, down=True, hop=b.hop,
                          parent=b.parent, depth=b.depth, start=b.start, members=b.members, owners=b.owners,
                          keys=b.keys, forms=b.forms, pin=b.pin)
