"""One agent per module for Funiak et al.'s distributed localization (§V): a thin driver over its phases.

A :class:`ModuleAgent` knows only its own id, its own observations z_{i,j} of its neighbours and what
arrives in its inbox. It composes one small object per phase of the distributed Algorithm 1
(:class:`~agents.modules.tree.TreePhase`: neighbour detection, election and trees;
:class:`~agents.modules.abstraction.AbstractionPhase`: size, clusters and cut;
:class:`~agents.modules.leaves.LeafPhase`; :class:`~agents.modules.alignment.AlignmentPhase`;
:class:`~agents.modules.refinement.RefinementPhase`), the group tree's convergecast
(:class:`~agents.modules.gather.Gather`) and its outgoing messages (:class:`~agents.modules.link.Link`),
routes each delivered message to the phase that handles its kind, and exposes the ``begin_*`` steps
the runner schedules. The runner only schedules phases (a round clock) and carries messages; it
reads no agent state apart from the final pose. The numerical work calls :mod:`decentral.ensemble`.
"""

from __future__ import annotations

import numpy as np

from agents.modules.abstraction import AbstractionPhase
from agents.modules.alignment import AlignmentPhase
from agents.modules.gather import Gather
from agents.modules.leaves import LeafPhase
from agents.modules.link import Link
from agents.modules.refinement import RefinementPhase
from agents.modules.state import LevelState, ModuleConfig
from agents.modules.tree import TreePhase
from protocols.ensemble.messages import ClusterClaim, Command, Hello, Join, PoseShare, Report, TreeFlood
from protocols.messages import Message

__all__ = ["ModuleConfig", "ModuleAgent", "LevelState"]


class ModuleAgent:
    """A module: config, private state, and its phases; one handler per message kind.

    Parameters
    ----------
    config : ModuleConfig
    rng : numpy.random.Generator
        The module's own stream (cluster-leader self-election).
    """

    def __init__(self, config: ModuleConfig, rng: np.random.Generator):
        self.config = config
        self.rng = rng
        self.id = int(config.module)
        self.name = str(self.id)
        d = config.dim
        self.z_out = {int(j): np.asarray(zz, float) for j, zz in zip(config.neighbours, config.z)}
        self.z_in: dict[int, np.ndarray] = {}
        self.position = np.zeros(d)
        self.rotation = np.eye(d)
        self.levels: dict[int, LevelState] = {}
        self.share_rounds = 0  # refinement iterations in which this module sent its pose (a local broadcast each)
        self.shares_sent = 0  # refinement pose shares sent (one per neighbour per iteration)
        self.events: list[str] = []  # leader-side notes (cut values, fallbacks)
        self.link = Link(self.name, config.reliable, config.retry_rounds)
        self.gather = Gather(self)
        self.tree = TreePhase(self)
        self.abstraction = AbstractionPhase(self)
        self.leaves = LeafPhase(self)
        self.alignment = AlignmentPhase(self)
        self.refinement = RefinementPhase(self)
        self._routes = {
            Hello: self.tree.on_hello, TreeFlood: self.tree.on_flood, Join: self.tree.on_join,
            ClusterClaim: self.abstraction.on_claim, Report: self.gather.on_report,
            Command: self.gather.on_command, PoseShare: self._on_pose,
        }
        # the steps the runner schedules, phase by phase
        self.begin_hello = self.tree.begin_hello
        self.begin_election = self.tree.begin_election
        self.begin_tree = self.tree.begin_tree
        self.begin_join = self.tree.begin_join
        self.begin_count = self.abstraction.begin_count
        self.begin_cluster = self.abstraction.begin_cluster
        self.begin_abstract = self.abstraction.begin_abstract
        self.begin_leaf = self.leaves.begin_leaf
        self.begin_boundary = self.alignment.begin_boundary
        self.begin_align = self.alignment.begin_align
        self.begin_refine = self.refinement.begin_refine
        self.refine_send = self.refinement.refine_send
        self.refine_update = self.refinement.refine_update
        self.begin_grad = self.refinement.begin_grad
        self.refining = self.refinement.refining

    # ------------------------------------------------------------------ the link's counters
    @property
    def sent(self):
        """Messages sent per phase (a Counter)."""
        return self.link.sent

    @property
    def _seq(self) -> int:
        return self.link.seq

    @_seq.setter
    def _seq(self, value: int) -> None:  # the batched refinement numbers its shares in the agent's sequence
        self.link.seq = value

    @property
    def outbox(self) -> list[Message]:
        return self.link.outbox

    # ------------------------------------------------------------------ the round
    def flush(self, round_: int) -> list[Message]:
        """Run the decisions due at the end of a round, retransmit what is overdue, and hand over the outbox."""
        self.link.round = round_
        for level, st in self.levels.items():
            if st.flood_in:
                self.tree.decide_flood(level, st)
            if st.cluster_in:
                self.abstraction.decide_cluster(level, st)
        return self.link.take(round_)

    @property
    def busy(self) -> bool:
        """Whether the agent still has something to send or to see acknowledged."""
        return self.link.busy or any(s.flood_in or s.cluster_in for s in self.levels.values())

    def handle(self, msg: Message) -> None:
        """Route one delivered message to its handler (duplicates of acknowledged messages are dropped)."""
        sender = int(msg.sender)
        if not self.link.accept(sender, msg):
            return
        route = self._routes.get(type(msg))
        if route is not None:
            route(sender, msg)

    def _on_pose(self, sender: int, msg: PoseShare) -> None:
        st = self.levels.get(msg.level)
        if st is None or st.group != msg.group:
            return
        pose = (np.asarray(msg.position, float), np.asarray(msg.rotation, float))
        if msg.phase == "boundary":  # a pose across the cut (alignment)
            st.boundary[sender] = pose
        else:  # a neighbour's pose of this refinement iteration
            st.nbr_pose[sender] = pose

    # ------------------------------------------------------------------ shared by the phases
    def level_state(self, level: int) -> LevelState:
        """The state of ``level``, created (group unknown) when first needed."""
        st = self.levels.get(level)
        if st is None:
            st = self.levels[level] = LevelState(-1)
        return st

    def pose(self) -> np.ndarray:
        """The own pose as sent: position then the rotation's entries."""
        return np.concatenate([self.position, self.rotation.ravel()])
