"""One agent's sharing of a window's cost forms: up and down the aggregation tree, or by broadcast.

The role the assembly agent (:mod:`agents.assembly`) plays every window before its ADMM rounds
(the agent's module docstring describes the protocol): it holds the window's records (every agent's
forms seen here, :class:`protocols.aggregation.TreeAggregation`), sends its bundle up and the final set
down, answers and repairs lost bundles, keeps a window that timed out without every agent's forms
open for late records, and says when the window's sharing is finished. The agent feeds it messages
(``on_*``), calls :meth:`WindowAggregation.progress` in its bootstrap phases, and takes the finished
window (:meth:`WindowAggregation.finish`) to solve and seed its ADMM. The window's state is typed
(:class:`protocols.window_share.WindowShare`); its joint solution (:func:`decentral.admm.solve_joint`,
once per window) is asked for here, because the reference sends it down instead of the forms.

How the forms travel:

* **tree** (``aggregation="tree"``, default, once the agent has a route to the reference): a
  convergecast up a spanning tree of the view graph to the reference agent and a broadcast back down
  (:mod:`protocols.aggregation`, ``admm.bundle`` / ``admm.bundle_ack``). Its parent is the neighbour
  with the smallest hop count to the reference (distance vector carried as the ``tree`` block of the
  ADMM messages, and filled at once from the view graph the forms of a complete window reveal). The
  reference's down bundle names the round at which every agent starts the ADMM, so agents near the
  reference do not spend rounds waiting for the far ones. Per window and agent without loss: one
  bundle up, and per child one acknowledgement and one bundle down.
* **broadcast** (the cold start, a restarted agent, a side of a partition without the reference, links
  so slow that a trip up and down the tree would outlast the share timeout (:attr:`WindowAggregation.slow_tree`),
  or ``aggregation="broadcast"``): ``admm.factors_delta`` to everyone (the forms of the window's last two
  steps and a digest of the rest, which receivers rebuild from the forms they hold), with the list of
  agents whose forms it has; agents missing from that list answer directly with every form. Messages
  per agent grow with the number of agents.

Byte budget (``docs/processes.md``): forms are shared one per pair and step (and per odometry link),
each built from its step's data alone, so a window adds one new step of forms; in the tree they go up
as ``admm.delta`` (only what the parent lacks, a digest per record:
:mod:`protocols.form_cache`), and once the reference holds every live agent's forms it sends its
joint solution down as ``admm.solution`` (float32 poses of the newest step) instead of the forms.

Nothing here reads a clock: the agent sets :attr:`WindowAggregation.round` and
:attr:`WindowAggregation.step` (its round and log step), and every message goes out through the
``send`` callable it passes in, in the order the protocol produces them.
"""

from __future__ import annotations

import copy
from typing import Callable, NamedTuple

import numpy as np

from protocols.admm_messages import FactorShare, FormAck, FormBundle, pack_forms
from protocols.aggregation import DownRepair, NeighbourTree, TreeAggregation
from protocols.delta_messages import DeltaBundle, FactorDelta, JointPoses
from protocols.form_cache import FormCache
from protocols.liveness import Liveness
from protocols.messages import BROADCAST, Message
from protocols.window_messages import WindowMessages
from protocols.window_share import NEVER, DownState, OwnForms, WindowShare

__all__ = ["WindowAggregation"]


class Owed(NamedTuple):
    """Records of window ``share`` that ``parent``'s partial down bundle lacked, last sent at round ``last``."""

    share: WindowShare
    parent: int
    indices: list[int]
    last: int

    def held(self, step: int, members) -> bool:
        """Whether ``members`` (of window ``step``, acknowledged or sent down by the parent) hold every owed record."""
        return self.share.step == step and set(self.indices) <= set(members)


class WindowAggregation:
    """The sharing of every window's cost forms at one agent (send and receive halves).

    Parameters
    ----------
    name : str
        The agent's assembly.
    assemblies : sequence of str
        Every assembly's name (agent indices are positions in it).
    reference : str
        The assembly pinning the gauge: the root of the tree.
    aggregation : {"tree", "broadcast"}
        How the forms travel once the agent has a route to the reference.
    window, share_timeout : int
        Sliding-window length, and rounds after which a window goes on with the forms it has.
    placement_limit : float
        Largest Laplace yaw std of an assembly the joint placement test places (rad).
    counters : dict
        The agent's counters (``retransmits``, ``ignored``, ``late_seeds``, ``tree_windows``,
        ``broadcast_windows``, ``joint_failures``, ``unrebuilt``: compact broadcasts whose record could not be
        rebuilt here, are counted here).
    send : callable
        Queues an outgoing message.

    Attributes
    ----------
    share : WindowShare or None
        The window whose forms are being shared (None once finished).
    late : WindowShare or None
        A finished window that timed out without every agent's forms: late records may complete it.
    down : DownState or None
        The final set of the last window as sent down.
    own : OwnForms or None
        The forms this agent shared for the current window.
    tree : NeighbourTree
        The neighbours' places in the tree.
    liveness : Liveness
        Who was heard lately, in windows listened through (:mod:`protocols.liveness`).
    messages : WindowMessages
        What goes out, built from a window's state (:mod:`protocols.window_messages`).
    """

    def __init__(self, name: str, assemblies, reference: str, *, aggregation: str, window: int, share_timeout: int,
                 placement_limit: float, counters: dict, send: Callable[[Message], None]):
        self.name, self.names, self.reference = name, tuple(assemblies), reference
        self.index = {a: i for i, a in enumerate(self.names)}
        self.me = self.index[name]
        self.aggregation, self.window, self.share_timeout = aggregation, window, share_timeout
        self.placement_limit = placement_limit
        self.counters, self._send = counters, send
        self.tree = NeighbourTree(self.names, self.me, self.index[reference], 2 * share_timeout)
        self.round = 0  # the agent's clock (set by the agent)
        self.step: int | None = None  # the agent's current log step (set by the agent)
        self.share: WindowShare | None = None
        self.late: WindowShare | None = None
        self.down: DownState | None = None
        self.own: OwnForms | None = None
        self.liveness = Liveness()  # the agent calls liveness.listened_through() after a window it listened in
        self.messages = WindowMessages(name, self.names, reference)
        #: records a parent's down bundle lacked (it timed out without them), sent again until the parent
        #: acknowledges them or the next window has gone by
        self.owed: Owed | None = None
        self.depth = 1  # depth of the aggregation tree in the last down bundle
        self.forms = FormCache()  # every agent's forms seen here for the window (rebuilds deltas from below)
        #: set by the agent when a trip up and down the tree takes longer than its share timeout at the measured
        #: lag: its windows are then shared by broadcast (one trip), whatever ``aggregation`` says
        self.slow_tree = False
        #: rounds before what was not answered is sent again (a broadcast, a bundle up, a request for the down
        #: bundle): 3, or a round trip at the measured lag when the agent sets it (resending sooner only queues
        #: copies behind the first on a slow link)
        self.resend_after = 3

    # ------------------------------------------------------------------ windows
    def heard(self, sender: int) -> None:
        """Agent ``sender`` was heard from (directly or through its records): alive, and waited for again by the
        open window (and by one that timed out here) if it had been given up on."""
        self.liveness.heard(sender)
        for share in (self.share, self.late):
            if share is not None:
                share.agg.expect(sender)

    def alive_members(self) -> set[int] | None:
        """Agents heard lately (:meth:`protocols.liveness.Liveness.alive_members`): a set of forms is complete once
        it holds theirs; ``None``: every agent."""
        return self.liveness.alive_members()

    def open(self, step: int, parent: int | None, hop: int | None, wait: int) -> None:
        """Start sharing window ``step`` below ``parent`` at ``hop`` hops from the reference (children: the
        neighbours that named this agent as their parent lately; ``wait``: rounds to wait for them)."""
        agg = TreeAggregation(self.me, len(self.names), root=self.name == self.reference, parent=parent,
                              children=self.tree.children(self.round, self.step), start=self.round + 1, wait=wait,
                              hop=hop or 0, expected=self.alive_members())
        self.share = WindowShare(step=step, agg=agg)
        self.own = None

    def slide(self, first: int) -> None:
        """Forms of steps before ``first`` left the window: they are no longer part of any record."""
        self.forms.slide(first)
        self.messages.slide(first)

    def share_own(self, forms: list, pin: np.ndarray) -> None:
        """Share this agent's forms ``[(keys, M, b_z, c_z, count)]`` (keys as agent index and step) of the window,
        by the tree when it has a route to the reference (or, at the reference, children), else by broadcast."""
        share = self.share
        agg = share.agg
        keys, flat = pack_forms(forms)
        self.own = OwnForms(share.step, keys, flat, pin, record=tuple(self.messages.problems(forms)))
        tree = (self.aggregation == "tree" and not self.slow_tree
                and (agg.parent is not None or agg.root and bool(agg.children)))
        share.mode = "tree" if tree else "broadcast"
        self.counters["tree_windows" if tree else "broadcast_windows"] += 1
        # own forms go through the same packing as everyone else's, so all agents sum identical numbers (by
        # broadcast, the float32 of the compact kind)
        own = self._factor_share(self.name, compact=not tree, every=True)
        self.on_factor_delta(own) if isinstance(own, FactorDelta) else self.on_factors(own)

    def progress(self, parent: int | None) -> bool:
        """One bootstrap phase: send what is owed; ``True`` when the window's sharing is finished (complete,
        final, or timed out: then children that reported get what this agent ends with)."""
        share = self.share
        agg = share.agg
        if share.start is None:
            share.start = self.round
        share.waited += 1
        elapsed = self.round - share.start
        if share.mode == "tree":
            self._tree_progress()
            # the root finishes (partial) at the timeout; below it, agents wait longer: an agent that starts the ADMM
            # without the set pulls its seeded neighbours off the fixed point (200+ rounds per window at 50 % loss)
            limit = self.share_timeout * (1 if agg.root else 2) + (agg.hop or 0)
        else:
            if self.own is not None and self.round - share.sent >= self.resend_after:
                # the first time what is new since the last broadcast, again (a peer still lacks them) every form
                self._send(self._factor_share(BROADCAST, compact=True, every=share.sent != NEVER))
                share.sent = self.round
            limit = self.share_timeout
        if share.mode == "broadcast" and agg.complete or agg.final or elapsed >= limit:
            if not agg.final:
                if share.mode == "tree" and not agg.root and parent is not None:
                    self.tree.drop(self.names[parent])  # a silent parent: choose again
                self._send_down()
            return True
        return False

    def finish(self) -> tuple[WindowShare, bool]:
        """Close the window's sharing: the window, and whether it stays open for late records (the tree
        timed out without every agent's forms and no joint solution came down)."""
        share, self.share, self.late = self.share, None, None
        partial = share.solution is None and share.mode == "tree" and not share.agg.complete
        if partial:
            # a shallow copy: the same records (late ones complete both), but its own timers, pin and a joint
            # solution not yet computed (the finished window's is of the partial set)
            self.late = copy.copy(share)
            self.late.asked, self.late.last = 0, self.round
        return share, partial

    # ------------------------------------------------------------------ the joint solution
    def joint(self, share: WindowShare):
        """The joint solution of a window's forms (computed once per window, :meth:`WindowShare.solve`), or
        ``None`` (no forms, the gauge's value at this window unknown here, or a failed solve)."""
        # the class-by-class lie tests cost about 3 solves per member: where one agent solves for all (the tree's
        # reference) and in the cold start, not at every agent of every broadcast window (slow links); the rule
        # is the same at every agent, so that their joint solutions stay the same
        classes = share.mode != "broadcast" or share.step == 0
        if not share.solved and not share.solve(self.reference, max(0, self.step - self.window + 1), classes):
            self.counters["joint_failures"] += 1
        return share.joint

    def placeable(self, share: WindowShare, joint) -> frozenset:
        """``(assembly, step)`` keys the centralized placement test places on the joint solution (relative
        to this agent at the current step)."""
        return share.placeable_keys(joint, self.name, self.step, self.placement_limit)

    def unplaced_reasons(self, share: WindowShare, joint) -> dict[str, str]:
        """Why the joint placement test leaves an assembly out at this step (assembly -> reason code)."""
        return share.unplaced(joint, self.names, self.name, self.step, self.placement_limit)

    # ------------------------------------------------------------------ send half
    def _tree_progress(self) -> None:
        """Send what the tree protocol owes now: the bundle up (or a resend), or at the root the bundle down."""
        share = self.share
        agg = share.agg
        if share.mode != "tree" or agg.final:
            return
        if agg.root:
            if agg.complete:
                self._send_down()
            return
        if agg.up_due(self.round):
            self._send_up(agg.take_up(self.round))
        elif agg.resend_due(self.round, self.resend_after, max(self.depth, agg.hop) + self.resend_after):
            # (a parent that stays silent is dropped at the window's timeout; switching to the broadcast after
            # a few unanswered resends instead cost 180-300 rounds per window at 50 % loss: it fired on loss alone)
            self.counters["retransmits"] += 1
            self._send_up(agg.take_resend(self.round), whole=True)

    def _bundle(self, receiver: str, indices, down: bool, start: int = 0,
                share: WindowShare | None = None) -> FormBundle:
        return self.messages.bundle(share or self.share, receiver, indices, down=down, round_index=self.round,
                                    start=start)

    def _send_up(self, indices: list[int], whole: bool = False, share: WindowShare | None = None,
                 parent: int | None = None) -> None:
        """Records ``indices`` of ``share`` (default: the open window) to ``parent`` (default: its parent): as a
        delta (what it lacks), or ``whole`` (a resend: it could not rebuild them, or the bundle was lost), as a
        delta that carries every form (float32, a quarter of a :class:`protocols.admm_messages.FormBundle`'s
        bytes: a frame of fewer datagrams survives loss more often)."""
        share = share or self.share
        parent = share.agg.parent if parent is None else parent
        delta = self.messages.delta(share, parent, indices, round_index=self.round, every=whole)
        self._send(delta or self._bundle(self.names[parent], indices, down=False, share=share))

    def _send_down(self, exclude=(), start: int | None = None) -> None:
        """The final set of this window to the children (the root: when complete or on timeout)."""
        share = self.share
        agg = share.agg
        agg.final = True
        if start is None:  # the root: when the deepest agent will have it, everyone starts the ADMM at once
            start = self.round + agg.depth // 2 + 2 if share.mode == "tree" and agg.root else 0
        share.start_at = start
        self.down = None
        if self.aggregation != "tree":
            return
        targets = agg.down_targets(exclude)
        # kept by every agent, so that any neighbour still waiting can be answered (packed when first asked)
        self.down = DownState(share, start, DownRepair(targets, start, self.round))  # children that may lack it
        for child in targets:
            self._send(self._down_bundle(self.names[child]))

    def _down_bundle(self, receiver: str) -> FormBundle | JointPoses:
        """What goes down to ``receiver``: the reference's joint solution when the set was complete there
        (:class:`protocols.delta_messages.JointPoses`, a few bytes per assembly), else the forms."""
        down = self.down
        share = down.share
        solution = share.solution
        if solution is None and self.name == self.reference and share.agg.complete:
            joint = self.joint(share)
            if joint is not None:
                solution = share.solution_out = share.solution_out or self._solution_message(share, joint)
        return down.to(self.name, receiver, self.round, solution, self.index[self.reference])

    def _solution_message(self, share: WindowShare, joint) -> JointPoses:
        placeable = {self.index[a] for a, k in self.placeable(share, joint) if k == share.step}
        return self.messages.solution(share, joint, placeable, self.round)

    def _factor_share(self, receiver: str, compact: bool = False, every: bool = False) -> FactorShare | FactorDelta:
        """The own forms to ``receiver``: as ``admm.factors``, or ``compact`` as ``admm.factors_delta`` (to everyone,
        unless ``every``, the forms not broadcast before and those of the window's last two steps; to one agent
        every form)."""
        if compact:
            return self.messages.factors_delta(self.own, self.share, receiver, self.round, every=every)
        return self.messages.factors(self.own, self.share, receiver, self.round)

    def ask(self, neighbour: str, step: int) -> None:
        """A neighbour sends ADMM values of window ``step``, so it has finished the sharing: ask it for the set
        (at most every other round) by sending it this agent's records, which it answers with the down bundle."""
        wait = self.share if self.share is not None else self.late
        if (wait is None or wait.step != step or wait.mode != "tree" or wait.agg.parent is None
                or self.round - wait.asked_at < 2):
            return
        wait.asked_at = self.round
        self.counters["retransmits"] += 1
        self._send(self._bundle(neighbour, sorted(wait.agg.records), down=False, share=wait))

    def ask_down(self) -> None:
        """After a timeout without every agent's forms, keep asking the parent for the down bundle (every
        :attr:`resend_after` rounds, at most 10 times this window): a late complete set re-seeds the window
        exactly."""
        late = self.late
        if (late is None or late.step != self.step or late.asked >= 10 or self.round - late.last < self.resend_after
                or late.agg.parent is None):
            return
        late.asked += 1
        late.last = self.round
        self.counters["retransmits"] += 1
        self._send(self._bundle(self.names[late.agg.parent], sorted(late.agg.records), down=False, share=late))

    def resend_owed(self) -> None:
        """Send the records a parent's partial down bundle lacked again (every :attr:`resend_after` rounds, every
        form carried) until it acknowledges them: its window, kept open for late records, may still complete
        (:meth:`_on_late`) and revise its answer. Given up once the window after theirs has gone by."""
        if self.owed is None:
            return
        share, parent, indices, last = self.owed
        if self.step is not None and share.step < self.step - 1:
            self.owed = None
            return
        if self.round - last < self.resend_after:
            return
        self.owed = Owed(share, parent, indices, self.round)
        self.counters["retransmits"] += 1
        self._send_up(indices, whole=True, share=share, parent=parent)

    def repair_down(self, heard: Callable[[str], bool]) -> None:
        """Send the down bundle again to children not ``heard`` from in this window's ADMM (it was lost).

        A child that has the down bundle starts the ADMM at its ``start`` round with everyone else, and its
        first values reach this agent (a view-graph neighbour) a round later; a child still silent
        2 rounds after that gets the bundle again, every 3 rounds, at most 4 times (it may no longer be a
        neighbour; it also asks by itself)."""
        down = self.down
        if down is not None and (down.share.solution or down.share.solution_out):
            return  # an exact window sends no ADMM values to tell it by: the children ask themselves
        if down is None or down.step != self.step or not down.repair:
            return
        for child in down.repair.due(self.round, lambda c: heard(self.names[c])):
            self.counters["retransmits"] += 1
            self._send(self._down_bundle(self.names[child]))

    # ------------------------------------------------------------------ receive half
    def on_ack(self, message: FormAck) -> None:
        """The parent acknowledges the bundle up, or a child says it has the down bundle."""
        share, down, owed = self.share, self.down, self.owed
        if owed is not None and self.index.get(message.sender) == owed.parent and owed.held(message.step,
                                                                                           message.have.tolist()):
            self.owed = None
        if share is not None and share.step == message.step and self.index.get(message.sender) == share.agg.parent:
            share.agg.acknowledge(message.have.tolist(), self.round)
        elif down is not None and down.step == message.step:
            down.repair.have(self.index.get(message.sender))  # a child has the down bundle

    def on_factors(self, message: FactorShare) -> None:
        """An agent's forms by broadcast (or its direct answer): kept, and answered when it lacks this agent's."""
        sender = self.index.get(message.sender)
        if sender is None or (len(message.keys) and message.keys[:, 1].max() >= len(self.names)):
            self.counters["ignored"] += 1
            return
        share = self.share
        if share is not None and message.step == share.step:
            if sender not in share.records:
                forms = self.messages.problems(message.unpack())
                self.forms.remember(sender, forms)
                self._take_factors(message, sender, forms)
            self._follow_parent(message, sender)
        self._answer_factors(message)

    def on_factor_delta(self, message: FactorDelta) -> None:
        """An agent's forms by compact broadcast (or its direct answer): the forms carried are kept, its record of
        the window rebuilt from them and those held here if its digest matches exactly (else it is left out of
        this agent's ``have``, and its next broadcast gets every form as an answer), and it is answered when it
        lacks this agent's forms."""
        sender, n = self.index.get(message.sender), len(self.names)
        if sender is None or (len(message.pairs) and message.pairs.max() >= n):
            self.counters["ignored"] += 1
            return
        carried = self.messages.problems(message.carried())
        digest = tuple(message.digest.tolist())
        if self.step is not None and self.step - self.window < message.step <= self.step + 1:
            # forms of windows that overlap this one (a peer's next window included: it may be a little ahead); older
            # or later ones are not kept, so the memory a peer's frames take here stays bounded
            self.forms.remember(sender, carried)
        share = self.share
        if share is not None and message.step == share.step:
            if sender not in share.records:
                # every form carried (an answer, a resend, the first broadcast), else rebuilt with those held here
                record = (FormCache.whole(carried, digest)
                          or self.forms.rebuild(sender, digest, message.step - self.window + 1, message.step))
                if record is None:
                    self.counters["unrebuilt"] += 1
                else:
                    self._take_factors(message, sender, record)
            self._follow_parent(message, sender)
        self._answer_factors(message)

    def _take_factors(self, message: FactorShare | FactorDelta, sender: int, forms: list) -> None:
        """Keep ``sender``'s record ``forms`` ``[(keys, LocalProblem)]`` of the open window, from ``message`` (the
        caller has put them in :attr:`forms`)."""
        share = self.share
        agg = share.agg
        # a record that came by broadcast to an agent of the tree goes up with its own: the agents decide
        # on the broadcast each from its own measured lag, and a tree's root waits for every record
        # (records an agent that broadcasts sent its tree neighbours never reached the root otherwise)
        forward = message.sender == self.name or (share.mode == "tree" and sender != agg.parent)
        agg.add({sender: forms}, forward=forward)
        if len(message.pin):
            share.pin = np.array(message.pin)

    def _follow_parent(self, message: FactorShare | FactorDelta, sender: int) -> None:
        """The tree parent broadcasts its forms: it has no route to the reference, nor has this agent."""
        share = self.share
        agg = share.agg
        if share.mode == "tree" and message.receiver == BROADCAST and agg.parent == sender and not agg.final:
            share.mode, share.sent = "broadcast", NEVER

    def _answer_factors(self, message: FactorShare | FactorDelta) -> None:
        """A broadcast of the own window's forms that lacks this agent's: answered directly with every form (only
        broadcasts are answered, so answers never ping-pong)."""
        own = self.own
        if (own is not None and own.step == message.step and message.receiver == BROADCAST
                and message.sender != self.name and self.me not in set(message.have.tolist())):
            self._send(self._factor_share(message.sender, compact=isinstance(message, FactorDelta)))

    def on_delta(self, message: DeltaBundle) -> bool:
        """A delta bundle from a child: rebuild each member's record of the window from the forms carried and
        those held here (:class:`protocols.form_cache.FormCache`); a member that cannot be rebuilt exactly is
        left out (not acknowledged: the child sends it whole). ``True``: the window's sharing finished."""
        n = len(self.names)
        if (self.index.get(message.sender) is None or (len(message.pairs) and message.pairs.max() >= n)
                or (len(message.members) and message.members.max() >= n)):
            self.counters["ignored"] += 1
            return False
        carried = {}
        for owner, keys, M, b_z, c_z, count in message.carried():
            forms = self.messages.problems([(keys, M, b_z, c_z, count)])
            self.forms.remember(owner, forms)
            carried.setdefault(owner, []).extend(forms)
        first = message.step - self.window + 1
        rebuilt = {}
        for member, digest in zip(message.members.tolist(), message.digest.tolist()):
            # a record carried whole (a resend) is taken as it came; else rebuilt from the forms held here
            record = FormCache.whole(carried.get(member, ()), tuple(digest)) \
                or self.forms.rebuild(member, tuple(digest), first, message.step)
            if record is not None:
                rebuilt[member] = record
        return self.on_bundle(message, rebuilt)

    def on_bundle(self, message: FormBundle | DeltaBundle, rebuilt: dict | None = None) -> bool:
        """A bundle from a child (records up) or from the parent (the final set, down); ``rebuilt``: the
        records a delta bundle describes (:meth:`on_delta`). ``True``: the window's sharing finished."""
        n = len(self.names)
        down = bool(getattr(message, "down", False))
        sender = self.index.get(message.sender)
        if rebuilt is None and (sender is None or (len(message.keys) and message.keys[:, 1].max() >= n)
                                or (len(message.members) and message.members.max() >= n)):
            self.counters["ignored"] += 1
            return False  # (a delta's indices were checked by on_delta)
        self.tree.heard(message.sender, message.hop, message.parent, self.round, self.step)
        for member in message.members.tolist():
            self.heard(int(member))
        if rebuilt is None:
            records = {i: self.messages.problems(forms) for i, forms in message.records().items()}
            for i, forms in records.items():
                self.forms.remember(i, forms)
        else:
            records = rebuilt
        owed = self.owed
        if down and owed is not None and owed.held(message.step, message.members.tolist()):
            self.owed = None  # a down bundle that holds them: the parent has them
        share, late = self.share, self.late
        if share is None and late is not None and late.step == message.step == self.step:
            return self._on_late(message, records, down, sender)
        if share is None or message.step != share.step:
            # finished with this window: a bundle from below means the down bundle was lost: send it again
            if not down and self.down is not None and self.down.step == message.step:
                self._send(self._down_bundle(message.sender))
            return False
        agg = share.agg
        if len(message.pin):
            share.pin = np.array(message.pin)
        if down:
            if agg.final:
                return False
            agg.add(records, depth=message.depth)
            self.depth = max(1, message.depth)
            lost = agg.missing_from(message.members.tolist())
            if lost and agg.parent is not None:  # the root timed out without records from here: send them again
                self.owed = Owed(share, agg.parent, lost, NEVER)
                self.resend_owed()
            self._send_down(exclude=(sender,), start=message.start)  # forwarded at once: one hop per phase
            # acknowledged: in an exact window no ADMM values come back to tell the parent it arrived
            self._send(share.ack(self.name, message.sender, self.round))
        else:
            agg.add(records, child=sender, depth=message.depth)
            if agg.final:  # already finished the window's sharing: the child missed the down bundle
                if self.down is not None:
                    self._send(self._down_bundle(message.sender))
                return False
            self._send(share.ack(self.name, message.sender, self.round))
            self._tree_progress()
        return False

    def _on_late(self, message, records: dict, down: bool, sender: int) -> bool:
        """Records of a window that finished here without every agent's forms: they may complete it."""
        late = self.late
        agg = late.agg
        if len(message.pin):
            late.pin = np.array(message.pin)
        new = agg.add(records, child=None if down else sender)
        if not down:  # (a child whose records a partial down bundle lacked sends them until they are acknowledged)
            self._send(late.ack(self.name, message.sender, self.round))
        if not down and new and agg.parent is not None:  # the root missed them too: pass them on
            self._send(self._bundle(self.names[agg.parent], sorted(new), down=False, share=late))
        if agg.complete:  # start again from the joint solution, and tell the children
            self.late, self.share = None, late
            agg.final = False
            self._send_down(exclude=(sender,) if down else (), start=0)
            self.counters["late_seeds"] += 1
            return True
        if not down and self.down is not None and self.down.step == message.step:
            self._send(self._down_bundle(message.sender))
        return False

    def on_solution(self, message: JointPoses) -> bool:
        """The reference's joint solution coming down: kept and forwarded to the children. ``True``: the
        window's sharing finished (the agent adopts it)."""
        if message.n != len(self.names):
            self.counters["ignored"] += 1
            return False
        share, late = self.share, self.late
        if share is None and late is not None and late.step == message.step == self.step:
            self.late, self.share = None, late  # a window that timed out here: complete after all
            late.agg.final = False
            share = late
            self.counters["late_seeds"] += 1
        if share is None or share.step != message.step or share.agg.final:
            return False
        self.tree.heard(message.sender, message.hop, message.parent, self.round, self.step)
        share.solution = message
        share.agg.depth = max(share.agg.depth, message.depth)
        self.depth = max(1, message.depth)
        # (not acknowledged: a child still without it after its bundle up was acknowledged sends the bundle again,
        # and whoever has finished the window answers with the solution)
        self._send_down(exclude=(self.index.get(message.sender),), start=message.start)
        return True
