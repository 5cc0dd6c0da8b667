"""The assembly agent: one per assembly, consensus-ADMM over the pairs it observes (:mod:`decentral.admm`).

An agent holds only what its assembly really has: its own node configuration, odometry and camera
detections (never ground truth), plus what arrives in its inbox. It is a thin composition of
protocol roles, each a small state machine in :mod:`protocols` with its own tests (house style 8-9).
Per log step it

1. back-projects its own detections (Liu et al. 2024 eq. (1), (4), :func:`decentral.pair_forms.own_detections`)
   and announces its configuration (:class:`protocols.config_gossip.ConfigGossip`: ``admm.config``, a
   broadcast when it changes, every ``announce_every`` steps a unicast to its current observers);
2. names the owner of every node it sees from the announced configurations and builds one
   directed pair subproblem ``self -> target`` per observed assembly over the sliding window
   (:func:`decentral.pair_forms.pair_forms`); an observer that detects nodes it cannot name asks with
   ``admm.config_request`` and does not report convergence while such nodes remain and some
   assembly's configuration is still missing (once it holds every configuration, nodes none of them
   lists are stray tags and are skipped);
3. shares its cost forms (``AgentConfig.share_forms``: at every step, the default, or at the run's
   first step only): the quadratic forms of the pairs it observes and of its own odometry chain
   (private data stay private; only these sums of squares travel), up and down a spanning tree to the
   reference or by broadcast (:class:`protocols.window_aggregation.WindowAggregation`). Once it holds
   every live agent's forms (or after ``share_timeout`` rounds) it solves the same joint problem
   (:func:`decentral.admm.solve_joint`, bit-identical everywhere), or adopts the reference's joint
   solution, and seeds its consensus poses, pair copies and duals there, a fixed point of the ADMM
   (:meth:`decentral.admm.PairState.seed`); the joint solution also fills the gossip table's rows of
   the step;
4. runs ADMM rounds, two phases each (:meth:`AssemblyAgent.tick`, :class:`protocols.admm_rounds.AdmmRounds`):
   phase 0 sends each observed assembly its pair's ``copy + dual`` (``admm.dual``), phase 1 updates
   its consensus poses and sends them to its observers (``admm.primal``). The rounds confirm the
   seeded fixed point, or finish the job for agents whose forms were missing.

Both ADMM kinds also carry (when it changed, see ``gossip_refresh``) a small gossip table
(:class:`protocols.pose_gossip.PoseGossip`: the newest consensus pose of every assembly at its latest
step) so every agent learns the poses of assemblies it does not talk to; :meth:`AssemblyAgent.estimates`
turns it into poses relative to the agent (Liu et al. 2024 eq. (19)). With every agent's forms in hand,
the joint solution only counts as the fixed point while its pairs are the ones its forms described.
A window that starts at the joint solution of every live agent's forms is exact and runs no ADMM
round (:meth:`AssemblyAgent._exact`); an agent joins the ADMM only while a neighbour runs it. Peers
not heard from for two windows are not waited for.
"""

from __future__ import annotations

import copy

import numpy as np

from agents.agent_config import AgentConfig, OwnStep
from agents.assembly_results import AssemblyResults
from agents.exclusion_revisions import ExclusionRevisions
from agents.window_start import WindowStart
from decentral.admm import ConsensusState, LocalProblem, PairState
from decentral.geometry import rot2
from decentral.pair_forms import own_detections, pair_forms
from protocols.admm_messages import ConfigAnnounce, ConfigRequest, FactorShare, FormAck, FormBundle
from protocols.messages import AdmmDual, AdmmPrimal, Message
from protocols.config_gossip import ConfigGossip
from protocols.lag import LagMeter
from protocols.delta_messages import DeltaBundle, FactorDelta, JointPoses
from protocols.pose_gossip import PoseGossip, pose_row
from protocols.admm_values import AdmmInbox
from protocols.window_aggregation import WindowAggregation
from protocols.admm_rounds import AdmmRounds, RoundView

__all__ = ["AgentConfig", "OwnStep", "AssemblyAgent", "LATE_WINDOWS"]

#: windows over which an agent remembers how late its process ran (:meth:`AssemblyAgent.ran_late`): the latest
#: of them counts, so one window on time does not switch a starved agent back to the tree
LATE_WINDOWS = 4



class AssemblyAgent(AssemblyResults):
    """Config + private state + message handlers (house style 9).

    Drive it with :meth:`on_step` once per log step, then per ADMM round deliver its inbox with
    :meth:`handle`, call :meth:`tick` (twice per round: phase 0 then phase 1) and send what
    :meth:`outbox` returns. :meth:`estimates` gives the poses it can place relative to itself and
    :attr:`converged` says whether its part of the consensus has converged.
    """

    def __init__(self, config: AgentConfig):
        self.config = config
        self._index = {name: i for i, name in enumerate(config.assemblies)}
        self._step: int | None = None
        self._t = 0.0
        self._steps: list[int] = []
        # own configuration's announcements, others' configurations, requests for unnamed nodes
        self._configs = ConfigGossip(config.name, config.assemblies, config.announce_every)
        self._seen: dict[int, list[tuple[int, np.ndarray, float]]] = {}  # step -> [(node, t, w)]
        self._odometry: dict[int, tuple] = {}
        self._pairs: dict[str, PairState] = {}
        self._pair_steps: set[int] = set()
        self._consensus = ConsensusState(config.name, config.name == config.reference)
        self._inbox = AdmmInbox()  # the newest ADMM values of each target and observer
        self._outbox: list[Message] = []
        self._dirty = True
        self._phase = 0
        self._round = 0
        self.counters = {"ignored": 0, "timeouts": 0, "retransmits": 0, "uncertified": 0, "unknown_nodes": 0,
                         "tree_windows": 0, "broadcast_windows": 0, "late_seeds": 0, "joint_failures": 0, "unrebuilt": 0}
        # the ADMM rounds: iteration counters, the last values sent, waiting counts and the convergence flag
        self._rounds = AdmmRounds(config.name, self._index[config.name], config.admm, patience=config.patience,
                                  window=config.window, share_timeout=config.share_timeout, counters=self.counters)
        # how late messages arrive (rounds): the waits below grow with it (Liu et al.'s window, over a slow radio)
        self._lag = LagMeter()
        self._patience = config.patience
        self._late: list[float] = []  # how late its process ran the last windows' half rounds (rounds; ran_late)
        self._start = WindowStart()  # the joint solution the current window started at, if any
        self._hold = 0  # the ADMM of this window starts at this round (after the forms are shared)
        self._hop: int | None = 0 if config.name == config.reference else None
        self._parent: int | None = None
        self._pair_sig: dict[str, int] = {}  # target -> detections used by its pair, at the last rebuild
        # the gossip table of every assembly's newest consensus pose (sent on the ADMM messages)
        self._gossip = PoseGossip(self._index[config.name], len(config.assemblies),
                                  min(config.admm.eps_rot, config.admm.eps_pos), config.gossip_refresh)
        #: set by the runtime's local rule (:class:`agents.runtime.LocalAgent`) once this agent's window is done:
        #: its ADMM values then carry a ``done`` block, so that quiet neighbours do not answer them
        self.window_done = False
        self._busy_seen = -(10**9)  # last round with ADMM values of this window from a neighbour still at work
        self._rounds_heard = 0  # rounds of the current window this agent ran (the clock of its peers' liveness)
        self._watchers: set[str] = set()  # observers named by the last complete set of forms
        self._shared: dict[str, list[LocalProblem]] = {}  # target -> its pair's forms, one per step
        #: members whose data the others' contradicted in the last window this agent solved (left out of it)
        self.excluded: tuple = ()
        self.suspects: tuple = ()  # inconsistent data, liar not identifiable: one of these (decentral.consistency)
        # the last exact windows it solved, answered again when a later window excludes a member they kept
        self._answered = ExclusionRevisions(config.window)
        self._revised: list[tuple[int, dict, dict]] = []  # (step, poses relative to it, unplaced) not yet taken
        # the sharing of every window's cost forms (tree or broadcast), its records and the neighbours' tree places
        limit = config.max_yaw_std if config.noise.weighting == "information" else np.inf
        self._sharing = WindowAggregation(config.name, config.assemblies, config.reference,
                                          aggregation=config.aggregation, window=config.window,
                                          share_timeout=config.share_timeout, placement_limit=limit,
                                          counters=self.counters, send=self._outbox.append)

    # ------------------------------------------------------------------ sensing
    @property
    def name(self) -> str:
        return self.config.name

    def advance(self, round_index: int) -> None:
        """The runtime's clock: the round under way, also while the agent runs no half rounds (quiet)."""
        if int(round_index) > self._round:
            self._rounds_heard += 1  # (a round it polled the network in; a process that fell behind jumps rounds)
        self._round = max(self._round, int(round_index))
        self._sharing.round = self._round

    @property
    def waits(self) -> dict[str, int]:
        """The waits in rounds now in force (``patience``, ``share_timeout``) and the measured one-way lag."""
        return {"patience": self._patience, "share_timeout": self._sharing.share_timeout,
                "lag": self._lag.one_way()}

    def _scale_waits(self) -> None:
        """Scale the waits to the measured lag (:mod:`protocols.lag`), never below the configured ones: a
        neighbour is silent after a round trip, and a window's forms may take a trip per tree level each way
        (once around a broadcast), plus the patience of the last one. Before any message arrived, the wait
        for the forms runs from the first one heard."""
        cfg = self.config
        self._patience = max(cfg.patience, self._lag.round_trip())
        depth = max(1, self._sharing.depth, self._sharing.tree.graph_depth)
        # a typical trip up (or down) the tree slower than the configured wait: broadcast (one trip, more messages).
        # A hop's trip is the link's lag plus the time the forwarding process runs late: on a computer busy with
        # other work the agents' processes are all late, each level of the tree adds that, and the reference
        # solving for all falls further behind (docs/processes.md, "Tree or broadcast, with busy cores")
        late = max(self._late, default=0.0)
        self._sharing.slow_tree = depth * (self._lag.typical() + late) > cfg.share_timeout
        hops = depth if cfg.aggregation == "tree" and not self._sharing.slow_tree else 1
        share_timeout = max(cfg.share_timeout, 2 * hops * self._lag.one_way() + self._patience)
        if not self._lag.heard:  # nothing arrived yet (a cold start over slow links): no wait can be judged yet
            share_timeout = max(share_timeout, self._round + cfg.share_timeout)
        self._rounds.patience, self._rounds.share_timeout = self._patience, share_timeout
        self._sharing.share_timeout = share_timeout
        self._sharing.resend_after = max(3, self._lag.round_trip())

    @property
    def sharing(self) -> str:
        """How this agent shares its windows' forms by its local rule, as of its last half round: ``"tree"``, or
        ``"broadcast"`` (so configured, or a trip through the tree too slow at the measured lag and lateness)."""
        return "broadcast" if self.config.aggregation == "broadcast" or self._sharing.slow_tree else "tree"

    def ran_late(self, rounds: float) -> None:
        """The runtime's report at a window's end: how late its process ran that window's half rounds (p90,
        in rounds). The latest of the last :data:`LATE_WINDOWS` reports adds to every hop of the tree's trip in
        the slow-tree test (:meth:`_scale_waits`). A simulated runner never reports: its agents run on time."""
        self._late = (self._late + [max(0.0, float(rounds))])[-LATE_WINDOWS:]

    def on_step(self, own: OwnStep, round_index: int | None = None) -> None:
        """Take the assembly's own observations of a new step (at round ``round_index``) and slide the window."""
        if round_index is not None:
            self.advance(round_index)
        cfg = self.config
        first = self._step is None and own.step == 0
        if self._step is not None and self._rounds_heard >= max(1, self._patience):
            self._sharing.liveness.listened_through()  # silence in that window counts
        self._rounds_heard = 0
        self._start = WindowStart()
        if cfg.share_forms == "every" or (cfg.share_forms == "first" and first):
            self._parent, self._hop = self._sharing.tree.position(self._round, self._step)
            self._sharing.open(own.step, self._parent, self._hop, self._patience)
        self._step, self._t = own.step, own.t
        self._sharing.step = own.step
        self._outbox += self._configs.set_own(own.config, own.step, self._round, self.observers)
        if own.odometry is not None:
            w_p, w_R = cfg.noise.odometry_weights()
            self._odometry[own.step] = (np.asarray(own.odometry.dp, float), float(own.odometry.dtheta), w_p, w_R)
        self._seen[own.step] = own_detections(cfg.cameras, own.detections, own.mounts, self._configs.own,
                                              cfg.node_radius, cfg.noise)
        first = max(0, own.step - cfg.window + 1)
        self._steps = list(range(first, own.step + 1))
        # forms of steps that left the window are no longer part of any record
        self._sharing.slide(first)
        for store in (self._seen, self._odometry):
            for k in [k for k in store if k < first]:
                del store[k]
        self._consensus.slide(self._steps, self._odometry)
        self._dirty = True
        self._rounds.new_window()
        # (a neighbour busy in the last window says nothing about this one: carried over, an exact window ran ADMM
        # rounds "to answer" it, its values made the neighbours busy in turn, and no window converged again)
        self._busy_seen = -(10**9)

    def seed(self, poses: dict) -> None:
        """Start the current window from a known joint solution ``(assembly, step) -> (R (2, 2), p (3,))``.

        Own consensus poses take their values; pairs built afterwards start at the solution with the
        duals that make it an ADMM fixed point (:meth:`decentral.admm.PairState.seed`).
        """
        self._start.seeds = dict(poses)
        self._consensus.seed({k: v for (a, k), v in poses.items() if a == self.name})
        for pair in self._pairs.values():
            pair.seed(self._start.seeds)
        self._dirty = True

    # ------------------------------------------------------------------ messages
    def handle(self, message: Message) -> None:
        """Route one received message by its type (anything else, or anything from a sender that is not one
        of the log's assemblies, is counted and ignored)."""
        sender = self._index.get(message.sender)
        if sender is None:
            self.counters["ignored"] += 1  # (a real transport refuses such frames before; the agent never trusts it)
            return
        sharing = self._sharing
        self._lag.observe(self._round - message.round)
        if self._step is not None:
            sharing.heard(sender)
        if isinstance(message, ConfigAnnounce):
            if self._configs.learn(message):
                self._dirty = True
        elif isinstance(message, FactorShare):
            sharing.on_factors(message)
        elif isinstance(message, FactorDelta):
            sharing.on_factor_delta(message)
        elif isinstance(message, (FormBundle, JointPoses, DeltaBundle)):
            finished = (sharing.on_bundle(message) if isinstance(message, FormBundle)
                        else sharing.on_solution(message) if isinstance(message, JointPoses)
                        else sharing.on_delta(message))
            if finished:
                self._finish_bootstrap()
        elif isinstance(message, FormAck):
            sharing.on_ack(message)
        elif isinstance(message, ConfigRequest):
            self._outbox += self._configs.answer(message, self._step, self._round)
        elif isinstance(message, (AdmmPrimal, AdmmDual)):
            if "done" not in message.blocks and message.window == self._step:
                self._busy_seen = self._round  # it runs the ADMM (late names, partial forms): take part
            self._gossip.merge(message.blocks.get("table"), self._round)
            b = message.blocks
            tree = b.get("tree")
            if tree is not None and tree.shape == (2,):
                sharing.tree.heard(message.sender, int(tree[0]), int(tree[1]), self._round, self._step)
            sharing.ask(message.sender, int(message.window))
            if not self._inbox.receive(message):
                self.counters["ignored"] += 1
        else:
            self.counters["ignored"] += 1

    @property
    def windows_independent(self) -> bool:
        """Each window starts from its own shared forms (``share_forms="every"``): an unfinished one can go on
        beside the next (:meth:`fork`); a plain consensus-ADMM carries its iterates from window to window."""
        return self.config.share_forms == "every"

    def fork(self) -> "AssemblyAgent":
        """An independent copy of this agent as it is now (its window, forms, ADMM state and outbox), sharing
        only the configuration and the counters: the runtime keeps an unfinished window going with it in the
        background (:class:`agents.runtime.LocalAgent`) while this agent takes the next sensor step."""
        twin = copy.deepcopy(self, {id(self.config): self.config, id(self.counters): self.counters})
        twin._sharing._send = twin._outbox.append  # (a bound method is copied as is: it would fill this outbox)
        return twin

    def outbox(self) -> list[Message]:
        """Messages queued since the last call (and forget them)."""
        out = list(self._outbox)
        self._outbox.clear()
        return out

    # ------------------------------------------------------------------ ADMM
    def _rebuild(self) -> None:
        """Directed pair subproblems ``self -> target`` over the window from own detections."""
        rows: dict[str, list] = {}
        unknown = set()
        for k in self._steps:
            for node, t, w in self._seen.get(k, []):
                hits = self._configs.owners_of(node, k)  # several: someone lies; each claim is tried
                if not hits:
                    unknown.add(int(node))
                    continue
                for owner, centre in hits:
                    rows.setdefault(owner, []).append((k, centre, t, w))
        self.counters["unknown_nodes"] = len(unknown)
        self._configs.unknown = unknown
        self._pair_steps = {k for r in rows.values() for k, *_ in r}
        self._pair_sig = {target: len(facts) for target, facts in rows.items()}
        for target in [t for t in self._pairs if t not in rows]:
            for store in (self._pairs, self._shared):
                store.pop(target, None)
            self._rounds.forget(target)
        for target, facts in rows.items():
            # the window's form for the ADMM, and the same factors step by step for sharing (a window adds its
            # newest step's form, bit-identical from window to window)
            problem, self._shared[target] = pair_forms(self.name, target, facts)
            pair = self._pairs.get(target) or PairState(self.name, target, self.config.admm)
            pair.set_problem(problem)
            if pair.iterations == 0 and not pair.y and self._start.seeds:
                pair.seed(self._start.seeds)
            self._pairs[target] = pair
        self._dirty = False

    def tick(self, round_index: int, phase: int | None = None) -> None:
        """Run the next phase of ADMM round ``round_index`` (phase 0: pairs; phase 1: consensus).

        ``phase`` names the half round explicitly (a runtime that skips the ticks of a quiet agent,
        :mod:`agents.runtime`); without it the phases alternate from call to call.
        """
        if phase is not None:
            self._phase = phase
        if self._step is None:
            return
        self._round = self._sharing.round = round_index
        self._scale_waits()
        self._parent, self._hop = self._sharing.tree.position(self._round, self._step)
        if self._phase == 0:
            self._sharing.resend_owed()
        if self._phase == 0 and self._sharing.share is None:
            self._sharing.repair_down(lambda name: self._inbox.heard_in(name, self._step))
            self._sharing.ask_down()
        if self._sharing.share is not None or round_index < self._hold:
            if self._phase == 0 and self._sharing.share is not None:
                self._bootstrap_phase()  # when it finishes, the ADMM starts at round `_hold` (at least the next)
            self._phase = 1 - self._phase
            return
        if self._dirty:
            self._rebuild()  # (a configuration that arrived may add a pair the joint solution lacks)
        if self._exact() and self._round - self._busy_seen > self._patience:
            # every live agent's forms and this agent's pairs as they described them: the joint solution is the
            # ADMM's fixed point, and every agent holding the set has it too; no round would change it (unless a
            # neighbour without the set has sent values lately: under loss they come every few rounds)
            self._rounds.converged = True
        elif self._phase == 0:
            self._start.admm_ran = True
            self._pair_phase()
        else:
            self._consensus_phase()
        self._phase = 1 - self._phase

    def _exact(self) -> bool:
        """The window started at the joint solution of every live agent's forms, its own pairs among them
        as they are now, and no node is left to name: the estimate is final without ADMM rounds."""
        return self._start.complete and self._start.form_sig == self._pair_sig and not self._unresolved()

    # ------------------------------------------------------------------ cold start
    def _request_unknown(self) -> None:
        self._outbox += self._configs.request(self._round, self._sharing.alive_members(), every=self._sharing.resend_after)

    def _bootstrap_phase(self) -> None:
        """Share the window's cost forms (up and down the tree, or by broadcast); then solve and seed."""
        sharing = self._sharing
        if self._dirty:
            self._rebuild()
        self._request_unknown()
        # an agent that did not run every step of the window (started late, restarted) holds none of its data of
        # the steps it missed: its forms would make the others' set look complete while it lacks them (a member
        # that skipped step 0 left windows 1-4 "converged" 1.5-19 mm from the centralized estimate), so it shares
        # nothing until its window holds only steps it ran; the others' windows then end partial, provisional
        ran_all = all(k in self._seen for k in self._steps)
        # nor while it sees nodes it cannot name yet (a configuration that has not arrived): forms without their
        # pairs made a complete set whose exact solution lacked them (over TCP stalls, windows "converged" 17-134
        # mm from the centralized estimate); stray tags no live assembly owns are not waited for (_unresolved)
        if sharing.own is None and ran_all and not self._unresolved():
            # one form per pair and step, and per odometry link: a window adds only its newest step's forms
            problems = [part for _, parts in sorted(self._shared.items()) for part in parts] \
                + self._consensus.odometry_links()
            forms = [(tuple((self._index[a], k) for a, k in prob.keys), prob.M, prob.b_z, prob.c_z, prob.count)
                     for prob in problems]
            pin = np.zeros(0)
            cons = self._consensus
            if cons.pinned and cons.pin is not None:
                pin = np.array([cons.pin[0], *cons.pin[2], cons.pin[1]])
            self._start.form_sig = dict(self._pair_sig)
            sharing.share_own(forms, pin)
        if sharing.progress(self._parent):
            self._finish_bootstrap()

    def _learn_graph(self, edges: set[tuple[int, int]]) -> None:
        """A complete window reveals the whole view graph: the neighbours' places in the tree (ready for the
        next window without waiting for the distance vector to cross the graph) and this agent's observers."""
        me = self._index[self.name]
        self._sharing.tree.learn(edges, self._round, self._step)
        self._watchers = {self.config.assemblies[a] for a, b in edges if b == me and a != me}

    def _fill_table(self, poses: dict) -> None:
        """The joint solution's poses of the current step into the gossip table (its own row too: in an exact
        window no ADMM round comes to write it)."""
        rows = [pose_row(self._index[name], step, self._round, R, p) for (name, step), (R, p) in poses.items()
                if step == self._step and name in self._index]
        self._gossip.fill(rows, self._round)

    def _fresh_admm(self) -> None:
        """A fresh ADMM start at the new window's fixed point: earlier values belong to the old window."""
        self._inbox.keep_from(self._step)
        self._rounds.restart()
        for pair in self._pairs.values():
            pair.y, pair.y_hat = {}, {}

    def _finish_bootstrap(self) -> None:
        """Solve the joint problem of the shared forms (:func:`decentral.admm.solve_joint`) and seed the ADMM,
        or adopt the joint solution the reference sent down (:class:`protocols.delta_messages.JointPoses`)."""
        sharing = self._sharing
        share, partial = sharing.finish()
        self._hold = max(share.start_at, self._round + 1)  # the ADMM starts with a later round's pair phase
        if share.solution is not None:
            self._adopt(share.solution)
            return
        if partial:
            # values from a partial solution would pull the neighbours that have the whole set off the exact
            # fixed point (100-250 rounds per window at 50 % loss): stay silent while the rest may still come
            self._hold = self._round + self._sharing.share_timeout
        joint = sharing.joint(share)
        self.excluded, self.suspects = tuple(share.excluded), tuple(share.suspects)
        if joint is None:
            return  # no forms, or the gauge's value at this window is unknown here: the ADMM goes on
        if share.agg.complete:
            self._answer_again_without(self.excluded)
            self._answered.record(self._step, max(0, self._step - self.config.window + 1), share)
        seeds = joint.poses
        # every agent's forms: the seeds are the joint estimate of this step (a fixed point of the ADMM),
        # and the centralized estimator's placement test can be run on them
        self._start.complete = share.agg.complete  # every (live) agent's forms
        if share.agg.complete:
            self._start.without = frozenset(n for i, n in enumerate(self.config.assemblies) if i not in share.agg.records)
        # (a set without some agent's forms is still the centralized problem of the data that arrived: its
        # placements answer the step if the ADMM has not converged when the next sensor step comes; without
        # them a window whose peer is down placed no one when that came before the wait for the forms ended)
        self._start.fallback = self._placed(seeds, sharing.placeable(share, joint))
        if self._start.complete:
            self._start.placeable = sharing.placeable(share, joint)
            self._start.why = sharing.unplaced_reasons(share, joint)
            # the joint solution already gives every assembly's pose of this step: the gossip table need
            # not cross the view graph before the convergence flag can settle (rounds flat in the diameter)
            self._fill_table(seeds)
            self._learn_graph(share.edges())
        # the seeded duals balance only with every observer's contribution: wait for their first values
        names = self.config.assemblies
        self._start.expected = {names[i] for i in share.observers_of(self._index[self.name])}
        if self.config.share_forms == "every":
            self._fresh_admm()
        self.seed(seeds)

    def _adopt(self, solution: JointPoses) -> None:
        """Start the window from the reference's joint solution: the newest step's poses (older window steps
        keep this agent's values: an exact window runs no ADMM round that would use them)."""
        names, me, step = self.config.assemblies, self._index[self.name], solution.step
        newest = {(names[i], step): (rot2(theta), p) for i, (p, theta) in solution.pose_of().items()
                  if i < len(names)}
        self._start.complete = True
        self._start.without = frozenset(names) - {names[i] for i in solution.indices("members") if i < len(names)}
        ref = self._index[self.config.reference]
        placeable = set(solution.indices("placeable")) | {ref}
        # placed relative to the reference; relative to this agent when it is placed itself
        self._start.placeable = frozenset((names[i], step) for i in placeable | {me} if i < len(names)) \
            if me in placeable else frozenset()
        self._start.fallback = self._placed(newest, self._start.placeable)
        self._fill_table(newest)
        if len(solution.edges):
            self._learn_graph({(a, b) for a, b in solution.edge_set() if a != b})
        self._start.expected = set()
        if self.config.share_forms == "every":
            self._fresh_admm()
        self.seed(newest)

    def settle_provisional(self) -> None:
        """The window ends (the next sensor step came, or the run ended) unconverged: its answer is the joint
        solution of the forms this agent holds now, placed by the centralized placement test (the centralized
        estimate of the data that arrived), instead of no answer at all or the solution of the fewer forms held
        when the wait for them ended (forms that came later count). An agent that adopted the reference's joint
        solution keeps it. The joint solution is solved again only if forms arrived since; nothing is sent."""
        share = self._sharing.share
        if share is None or self._step is None or share.solution is not None:
            return
        joint = self._sharing.joint(share)
        if joint is not None:
            self._start.fallback = self._placed(joint.poses, self._sharing.placeable(share, joint))

    def _answer_again_without(self, excluded: tuple) -> None:
        """Earlier exact windows that kept a member this window excludes, answered again without it
        (:class:`agents.exclusion_revisions.ExclusionRevisions`; taken with :meth:`take_revisions`)."""
        if not excluded:
            return
        limit = self._sharing.placement_limit
        for step, share in self._answered.revise(excluded, self.config.reference):
            placed = self._placed(share.joint.poses, share.placeable_keys(share.joint, self.name, step, limit), step)
            unplaced = share.unplaced(share.joint, self.config.assemblies, self.name, step, limit)
            self._revised.append((step, self._relative_to_own(self._rows_of(placed, step)), unplaced))

    def take_revisions(self) -> list[tuple[int, dict, dict]]:
        """Steps answered again since the last call, ``(step, poses relative to this agent, unplaced reasons)``
        (and forget them)."""
        out, self._revised = self._revised, []
        return out

    def _placed(self, poses: dict, placeable, step: int | None = None) -> dict[str, tuple]:
        """The poses at ``step`` (default: this step) of a joint solution ``(assembly, step) -> (R, p)`` that
        ``placeable`` names, and its own."""
        step = self._step if step is None else step
        return {name: pose for (name, k), pose in poses.items()
                if k == step and ((name, k) in placeable or name == self.name)}

    def _pair_phase(self) -> None:
        """Phase 0: each owned pair iterates once the target's consensus of its iteration has arrived."""
        if self._dirty:
            self._rebuild()
        self._request_unknown()
        self._outbox += self._rounds.pair_phase(self._view())

    def _consensus_phase(self) -> None:
        """Phase 1: the consensus update once every pair's copies of the next iteration are in."""
        self._outbox += self._rounds.consensus_phase(self._view())

    def _view(self) -> RoundView:
        """The window as the ADMM rounds see it at this round."""
        place = None
        if self.config.aggregation == "tree":
            place = (-1 if self._hop is None else self._hop, -1 if self._parent is None else self._parent)
        return RoundView(round=self._round, step=self._step, pairs=self._pairs, consensus=self._consensus,
                         inbox=self._inbox, gossip=self._gossip, seeds=self._start.seeds,
                         seeds_complete=self._start.complete, forms_current=self._start.form_sig == self._pair_sig,
                         expected=frozenset(self._start.expected), pair_steps=frozenset(self._pair_steps),
                         unresolved=bool(self._unresolved()), done=self.window_done, place=place)

    def _unresolved(self) -> set[int]:
        """Unnamed nodes that an assembly whose configuration has not arrived here may still own
        (:meth:`protocols.config_gossip.ConfigGossip.unresolved`)."""
        return self._configs.unresolved(self._sharing.alive_members())
