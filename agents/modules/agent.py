"""One agent per module for Funiak et al.'s distributed localization (§V): config, private state, handlers.

A :class:`ModuleAgent` knows only its own id, its own observations z_{i,j} of its neighbours and what
arrives in its inbox. It runs every phase of the distributed Algorithm 1 for every level of the
hierarchy it takes part in:

1. neighbour detection: tell each neighbour j the observation z_{i,j} (j needs it for its residuals);
2. leader election and spanning tree: at level 0 the smallest id floods the group (min-id election;
   the flood's shortest-path tree is the group tree); below, the leader named by the parent group
   floods its part. Every module registers with its parent (``Join``);
3. graph abstraction: modules elect themselves cluster leaders with a small probability and join the
   nearest one by hop count (ties to the smaller leader id); the abstract graph is aggregated to the
   group leader (with one module per cluster when the group is small: the exact cut);
4. normalized cut at the group leader; the parts, their leaders (smallest id) and sizes are
   disseminated down the tree. A part no larger than the leaf size is a leaf, localized by its
   leader from the gathered observations with the centralized leaf routine (Algorithm 1 line 2);
5. rigid alignment: modules on the cut exchange poses, aggregate the alignment statistics of their
   observations across the cut to the group leader, which solves eq. (5) and disseminates the
   transforms;
6. refinement: each module repeatedly replaces its own pose by the best one given its neighbours'
   (one message per neighbour per iteration); every few iterations the largest gradient entry is
   aggregated to the leader, which says whether to go on.

The runner only schedules phases (a round clock) and carries messages; it reads no agent state
apart from the final pose. The numerical work calls :mod:`decentral.ensemble`.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import numpy as np

from decentral.ensemble import AlignmentStats, EnsembleProblem, HierarchyConfig, merge_point_pairs, refine
from decentral.ensemble.model import fit_orientations, gradient
from decentral.ensemble.placement import place_breadth_first
from decentral.ensemble.rotation import matrix_to_angle, matrix_to_quat
from protocols.ensemble.aggregation import Convergecast, split_by_subtree
from protocols.ensemble.leader import CutPlan, cut_clusters, plan_merge
from protocols.ensemble.messages import (
    SUBPHASE_OF,
    Ack,
    ClusterClaim,
    Command,
    Hello,
    Join,
    PoseShare,
    Report,
    TreeFlood,
)
from protocols.messages import Message

__all__ = ["ModuleConfig", "ModuleAgent", "LevelState"]


@dataclass(frozen=True)
class ModuleConfig:
    """What a module knows before it starts (immutable).

    Attributes
    ----------
    module : int
        Its id.
    dim : int
        2 or 3.
    radius : float
        Module radius (metres).
    neighbours : ndarray of int, shape (k,)
        Modules it observed.
    z : ndarray, shape (k, dim)
        Its observations z_{module, neighbour} (own frame).
    hierarchy : HierarchyConfig
        Leaf size, abstraction size and refinement tolerances (shared with the centralized method).
    check_every : int
        Refinement iterations between two convergence checks.
    level_max_iter, top_max_iter : int
        Caps on refinement iterations below the top and at the top.
    step : float
        Damping of the position update (1 = jump to the local optimum).
    momentum : float
        Heavy-ball momentum of the position update (0 = plain damped Jacobi; 0.9 needs about a
        tenth of the iterations on a rotated seam).
    top_gtol : float
        Gradient tolerance (module radii) of the top-level refinement; below the top the
        hierarchy's ``level_refine.gtol`` applies.
    reliable : bool
        Acknowledge and retransmit every message (for lossy networks). A refinement iteration then
        waits until every share of that iteration has arrived, so a lossy run computes exactly what
        a lossless one does, at the price of the retransmissions and acknowledgements.
    retry_rounds : int
        Rounds without an acknowledgement before a retransmission.
    """

    module: int
    dim: int
    radius: float
    neighbours: np.ndarray
    z: np.ndarray
    hierarchy: HierarchyConfig = HierarchyConfig()
    check_every: int = 10
    level_max_iter: int = 400
    top_max_iter: int = 3000
    step: float = 1.0
    momentum: float = 0.9
    top_gtol: float = 1e-4
    reliable: bool = False
    retry_rounds: int = 3


class LevelState:
    """A module's private state for one level of the hierarchy."""

    __slots__ = (
        "group", "size", "leaf", "hops", "parent", "joined", "children", "nbrs", "nbr_next",
        "flood_in", "cluster", "cluster_in", "nbr_cluster", "cc", "plan", "boundary",
        "active", "iteration", "nbr_pose", "last_grad", "part_index", "previous",
    )

    def __init__(self, group: int, size: int = -1):
        self.group = group
        self.size = size
        self.leaf = False
        self.hops = -1
        self.parent = -1
        self.joined = False
        self.children: set[int] = set()
        self.nbrs: list[int] = []
        self.nbr_next: dict[int, int] = {}
        self.flood_in: list[tuple] = []
        self.cluster = -1
        self.cluster_in: list[tuple] = []
        self.nbr_cluster: dict[int, int] = {}
        self.cc: dict[str, tuple[Convergecast, dict]] = {}
        self.plan: CutPlan | None = None
        self.boundary: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self.active = False
        self.iteration = 0
        self.nbr_pose: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self.last_grad = np.inf
        self.part_index: dict[int, int] = {}
        self.previous: np.ndarray | None = None


class ModuleAgent:
    """A module: config, private state, and one handler per message kind.

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
        self.round = 0
        self.outbox: list[Message] = []
        self.sent = Counter()  # messages sent per phase
        self.share_rounds = 0  # refinement iterations in which this module sent its pose (a local broadcast each)
        self.shares_sent = 0  # refinement pose shares sent (one per neighbour per iteration)
        self._seq = 0
        self._pending: dict[tuple[int, int], list] = {}
        self._seen: set[tuple[int, int]] = set()
        self.events: list[str] = []  # leader-side notes (cut values, fallbacks)

    # ------------------------------------------------------------------ sending
    def _send(self, msg_type, receiver: int, step: str, reliable: bool = True, **fields) -> None:
        seq = -1
        if reliable and self.config.reliable:
            seq = self._seq
            self._seq += 1
        msg = msg_type(sender=self.name, receiver=str(receiver), round=self.round, seq=seq, **fields) \
            if msg_type is not Ack else msg_type(sender=self.name, receiver=str(receiver), round=self.round, **fields)
        self.outbox.append(msg)
        self.sent[SUBPHASE_OF.get(step, step)] += 1
        if seq >= 0:
            self._pending[(receiver, seq)] = [msg, step, None]  # None: not yet handed to the network

    def flush(self, round_: int) -> list[Message]:
        """Run the decisions due at the end of a round, retransmit what is overdue, and hand over the outbox."""
        self.round = round_
        for level, st in self.levels.items():
            if st.flood_in:
                self._decide_flood(level, st)
            if st.cluster_in:
                self._decide_cluster(level, st)
        if self._pending:
            for key, item in self._pending.items():
                msg, step, sent_at = item
                if sent_at is None:  # its first copy leaves in this outbox: the retry clock starts now
                    item[2] = round_
                elif round_ - sent_at >= self.config.retry_rounds:
                    self.outbox.append(msg)
                    self.sent[SUBPHASE_OF.get(step, step)] += 1
                    item[2] = round_
        out, self.outbox = self.outbox, []
        return out

    @property
    def busy(self) -> bool:
        """Whether the agent still has something to send or to see acknowledged."""
        return bool(self.outbox or self._pending or any(s.flood_in or s.cluster_in for s in self.levels.values()))

    # ------------------------------------------------------------------ receiving
    def handle(self, msg: Message) -> None:
        """Route one delivered message to its handler (duplicates of acknowledged messages are dropped)."""
        sender = int(msg.sender)
        if isinstance(msg, Ack):
            self._pending.pop((sender, msg.seq), None)
            return
        seq = getattr(msg, "seq", -1)
        if seq >= 0:
            self._send(Ack, sender, _step_of(msg), reliable=False, seq=seq, phase=_step_of(msg))
            if (sender, seq) in self._seen:
                return
            self._seen.add((sender, seq))
        if isinstance(msg, Hello):
            self.z_in[sender] = np.asarray(msg.z, float)
        elif isinstance(msg, TreeFlood):
            self._on_flood(sender, msg)
        elif isinstance(msg, Join):
            self._level(msg.level).children.add(sender)
        elif isinstance(msg, ClusterClaim):
            st = self.levels.get(msg.level)
            if st is not None and st.group == msg.group:
                st.nbr_cluster[sender] = msg.leader
                st.cluster_in.append((msg.hops, msg.leader))
        elif isinstance(msg, Report):
            self._on_report(sender, msg)
        elif isinstance(msg, Command):
            self._on_command(msg.level, msg.phase, {k: np.asarray(v) for k, v in msg.payload.items()})
        elif isinstance(msg, PoseShare):
            st = self.levels.get(msg.level)
            if st is None or st.group != msg.group:
                return
            pose = (np.asarray(msg.position, float), np.asarray(msg.rotation, float))
            if msg.phase == "boundary":
                st.boundary[sender] = pose
            else:
                st.nbr_pose[sender] = pose

    def _level(self, level: int) -> LevelState:
        st = self.levels.get(level)
        if st is None:
            st = self.levels[level] = LevelState(-1)
        return st

    # ------------------------------------------------------------------ 1. neighbour detection
    def begin_hello(self) -> None:
        for j, zz in self.z_out.items():
            self._send(Hello, j, "neighbor_detection", z=zz)

    # ------------------------------------------------------------------ 2. leader election and trees
    def begin_election(self) -> None:
        """Level 0: every module is a candidate; the smallest id wins by flooding."""
        st = self._level(0)
        st.nbrs = sorted(self.z_out)
        st.hops, st.parent, st.joined = 0, -1, True
        if st.nbrs and min(st.nbrs) < self.id:
            # a neighbour has a smaller id, so this module cannot win: it only relays (fewer floods)
            st.group = _NOBODY
            return
        st.group = self.id
        for j in st.nbrs:
            self._send(TreeFlood, j, "leader_election", level=0, group=self.id, hops=0)

    def begin_tree(self, level: int) -> None:
        """Below level 0 the part leader (named by the parent group) floods its part."""
        st = self.levels.get(level)
        if st is None or st.group != self.id:
            return
        st.hops, st.parent, st.joined = 0, -1, True
        for j in self.levels[level - 1].nbrs:
            self._send(TreeFlood, j, "leader_election", level=level, group=self.id, hops=0)

    def _on_flood(self, sender: int, msg: TreeFlood) -> None:
        level = msg.level
        if level > 0:
            above = self.levels.get(level - 1)
            if above is not None:
                above.nbr_next[sender] = msg.group
            st = self.levels.get(level)
            if st is None or st.group != msg.group:
                return
            st.flood_in.append((msg.hops + 1, sender, msg.group))
        else:
            st = self._level(0)
            st.flood_in.append((msg.hops + 1, sender, msg.group))

    def _decide_flood(self, level: int, st: LevelState) -> None:
        arrivals, st.flood_in = st.flood_in, []
        if level == 0:
            # min-id election: adopt a smaller group id, or the same id by a shorter path
            hops, sender, group = min(arrivals, key=lambda a: (a[2], a[0], a[1]))
            if (group, hops) < (st.group, st.hops):
                st.group, st.hops, st.parent = group, hops, sender
                for j in st.nbrs:
                    self._send(TreeFlood, j, "leader_election", level=0, group=group, hops=hops)
            return
        if st.joined:
            return
        hops, sender, group = min(arrivals)
        st.hops, st.parent, st.joined = hops, sender, True
        for j in self.levels[level - 1].nbrs:
            self._send(TreeFlood, j, "leader_election", level=level, group=group, hops=hops)

    def begin_join(self, level: int) -> None:
        """After the flood has settled: register with the parent; learn the same-group neighbours."""
        st = self.levels.get(level)
        if st is None:
            return
        if level > 0:
            above = self.levels[level - 1]
            st.nbrs = sorted(j for j in above.nbrs if above.nbr_next.get(j) == st.group)
        if st.parent >= 0:
            self._send(Join, st.parent, "leader_election", level=level, group=st.group)

    # ------------------------------------------------------------------ convergecast / dissemination
    def _cc_begin(self, level: int, step: str, own: dict) -> None:
        st = self.levels[level]
        early = st.cc.get(step)
        # a child's report may have arrived before this node began the step: keep it
        cc = early[0] if early is not None and early[1] is _NOT_YET else Convergecast(step, st.children)
        st.cc[step] = (cc, own)
        self._cc_try(level, step)

    def _cc_try(self, level: int, step: str) -> None:
        st = self.levels[level]
        cc, own = st.cc[step]
        if own is None or not cc.complete:
            return
        total = cc.result(own)
        st.cc[step] = (cc, None)  # done: keep the children's reports (the leaf step needs them)
        if st.parent >= 0:
            self._send(Report, st.parent, step, level=level, group=st.group, phase=step, payload=total)
        else:
            self._lead(level, step, total)

    def _on_report(self, sender: int, msg: Report) -> None:
        st = self.levels.get(msg.level)
        if st is None or st.group != msg.group:
            return
        if msg.phase not in st.cc or st.cc[msg.phase][1] is None:
            st.cc[msg.phase] = (Convergecast(msg.phase, st.children), _NOT_YET)
        cc, own = st.cc[msg.phase]
        cc.receive(sender, {k: np.asarray(v) for k, v in msg.payload.items()})
        if own is not _NOT_YET:
            self._cc_try(msg.level, msg.phase)

    def _disseminate(self, level: int, step: str, payload: dict) -> None:
        st = self.levels[level]
        for c in sorted(st.children):
            self._send(Command, c, step, level=level, group=st.group, phase=step, payload=payload)

    # ------------------------------------------------------------------ level 0 size
    def begin_count(self) -> None:
        self._cc_begin(0, "count", {"size": np.array([1], dtype=np.int64)})

    # ------------------------------------------------------------------ 3. graph abstraction
    def begin_cluster(self, level: int) -> None:
        st = self.levels.get(level)
        if st is None or st.leaf:
            return
        h = self.config.hierarchy
        exact = h.cut == "exact" or st.size <= 4 * h.abstract_size
        if exact:  # one module per cluster: the exact normalized cut
            st.cluster = self.id
            st.nbr_cluster = {j: j for j in st.nbrs}
            return
        p = min(1.0, h.abstract_size / max(st.size, 1))
        if self.id == st.group or self.rng.random() < p:
            st.cluster = self.id
            for j in st.nbrs:
                self._send(ClusterClaim, j, "graph_abstraction", level=level, group=st.group, leader=self.id, hops=1)

    def _decide_cluster(self, level: int, st: LevelState) -> None:
        arrivals, st.cluster_in = st.cluster_in, []
        if st.cluster >= 0:
            return
        hops, leader = min(arrivals)
        st.cluster = leader
        for j in st.nbrs:
            self._send(ClusterClaim, j, "graph_abstraction", level=level, group=st.group, leader=leader, hops=hops + 1)

    def begin_abstract(self, level: int) -> None:
        st = self.levels.get(level)
        if st is None or st.leaf:
            return
        nb = [j for j in st.nbrs if j in st.nbr_cluster]
        own = {
            "ea": np.full(len(nb), st.cluster, dtype=np.int64),
            "eb": np.array([st.nbr_cluster[j] for j in nb], dtype=np.int64),
            "ew": np.ones(len(nb), dtype=np.int64),
            "cid": np.array([st.cluster], dtype=np.int64),
            "csize": np.array([1], dtype=np.int64),
            "cmin": np.array([self.id], dtype=np.int64),
        }
        self._cc_begin(level, "abstract", own)

    # ------------------------------------------------------------------ leader decisions
    def _lead(self, level: int, step: str, total: dict) -> None:
        st = self.levels[level]
        if step == "count":
            st.size = int(total["size"][0])
            self._on_command(level, "count", {"size": total["size"]})
        elif step == "abstract":
            cid = total["cid"]
            if cid.size < 2:  # a single cluster cannot be cut: localize the group as one leaf
                self.events.append(f"level {level} group {st.group}: one cluster, solved as a leaf")
                plan = CutPlan(cid, np.zeros(1, dtype=np.int64), np.array([self.id]), np.array([st.size]), 0.0)
            else:
                # Funiak et al. 2008 eq. (4) on the aggregated abstract graph (Algorithm 1 line 4)
                plan = cut_clusters(total["ea"], total["eb"], total["ew"], cid, total["csize"], total["cmin"])
            st.plan = plan
            self._on_command(level, "cut", {
                "cluster_ids": plan.cluster_ids, "cluster_part": plan.cluster_part,
                "part_leader": plan.part_leader, "part_size": plan.part_size,
                "single": np.array([cid.size < 2]),
            })
        elif step == "leaf":
            self._solve_leaf(level, total)
        elif step == "align":
            plan = st.plan
            T = plan_merge(plan.part_leader, plan.part_size, total["pa"], total["pb"], total["stats"], total["links"])
            parts = np.array(sorted(T), dtype=np.int64)
            self._on_command(level, "align", {
                "parts": parts,
                "R": np.stack([T[int(p)].R for p in parts]),
                "t": np.stack([T[int(p)].t for p in parts]),
            })
        elif step == "grad":
            cap = self.config.top_max_iter if level == 0 else self.config.level_max_iter
            gtol = self.config.top_gtol if level == 0 else self.config.hierarchy.level_refine.gtol
            stop = bool(total["g"][0] <= gtol or st.iteration >= cap)
            self._on_command(level, "grad", {"stop": np.array([stop]), "g": total["g"]})

    def _on_command(self, level: int, step: str, payload: dict) -> None:
        st = self.levels[level]
        if step == "count":
            st.size = int(payload["size"][0])
            st.leaf = st.size <= self.config.hierarchy.leaf_size
            self._disseminate(level, step, payload)
        elif step == "cut":
            ids = payload["cluster_ids"]
            k = int(np.searchsorted(ids, st.cluster))
            part = int(payload["cluster_part"][k]) if k < ids.size and ids[k] == st.cluster else 0
            nxt = LevelState(int(payload["part_leader"][part]), int(payload["part_size"][part]))
            nxt.leaf = bool(payload["single"][0]) or nxt.size <= self.config.hierarchy.leaf_size
            self.levels[level + 1] = nxt
            self._disseminate(level, step, payload)
        elif step == "leaf":
            row = np.flatnonzero(payload["ids"] == self.id)
            if row.size:
                self.position = payload["pos"][row[0]].copy()
                self.rotation = payload["rot"][row[0]].copy()
            cc = st.cc["leaf"][0]
            members = {c: cc.received[c]["ids"] for c in cc.received}
            for c, sub in split_by_subtree(payload["ids"], {"pos": payload["pos"], "rot": payload["rot"]}, members).items():
                self._send(Command, c, step, level=level, group=st.group, phase=step, payload=sub)
        elif step == "align":
            mine = self.levels[level + 1].group
            k = int(np.flatnonzero(payload["parts"] == mine)[0])
            R, t = payload["R"][k], payload["t"][k]
            # Algorithm 1 line 10: x_B <- R x_B + t
            self.position = R @ self.position + t
            self.rotation = R @ self.rotation
            self._disseminate(level, step, payload)
        elif step == "grad":
            if bool(payload["stop"][0]):
                st.active = False
            self._disseminate(level, step, payload)

    # ------------------------------------------------------------------ 4. leaves
    def begin_leaf(self, level: int) -> None:
        st = self.levels.get(level)
        if st is None or not st.leaf:
            return
        nb = st.nbrs
        own = {
            "ids": np.array([self.id], dtype=np.int64),
            "oi": np.full(len(nb), self.id, dtype=np.int64),
            "oj": np.array(nb, dtype=np.int64),
            "oz": np.array([self.z_out[j] for j in nb], dtype=float).reshape(len(nb), self.config.dim),
        }
        self._cc_begin(level, "leaf", own)

    def _solve_leaf(self, level: int, total: dict) -> None:
        cfg = self.config
        ids = np.sort(total["ids"])
        index = {int(m): k for k, m in enumerate(ids)}
        order = np.lexsort((total["oj"], total["oi"]))
        i = np.array([index[int(m)] for m in total["oi"][order]], dtype=np.int64)
        j = np.array([index[int(m)] for m in total["oj"][order]], dtype=np.int64)
        sub = EnsembleProblem(cfg.dim, ids.size, cfg.radius, i, j, total["oz"][order])
        # Algorithm 1 line 2: local heuristic on a small set, then refinement (as centralized)
        rcfg = cfg.hierarchy.final_refine if level == 0 else cfg.hierarchy.level_refine
        pos, rot, _ = place_breadth_first(sub)
        res = refine(sub, pos, rot, rcfg)
        self._on_command(level, "leaf", {"ids": ids, "pos": res.position, "rot": res.rotation})

    # ------------------------------------------------------------------ 5. rigid alignment
    def begin_boundary(self, level: int) -> None:
        st = self.levels.get(level)
        if st is None or st.leaf or level + 1 not in self.levels:
            return
        mine = self.levels[level + 1].group
        for j in st.nbrs:
            if st.nbr_next.get(j, mine) != mine:
                self._send(PoseShare, j, "boundary", level=level, group=st.group, phase="boundary", iteration=0,
                           pose=self._pose())

    def begin_align(self, level: int) -> None:
        st = self.levels.get(level)
        if st is None or st.leaf or level + 1 not in self.levels:
            return
        mine = self.levels[level + 1].group
        d = self.config.dim
        keys, rows = [], []
        for j, (pj, rj) in sorted(st.boundary.items()):
            # Algorithm 1 lines 7-8 for the observation pair across the cut, via the centralized routine
            p, q = merge_point_pairs(self.position[None], self.rotation[None], pj[None], rj[None],
                                     self.z_out[j][None], self.z_in[j][None])
            keys.append(st.nbr_next[j])
            rows.append(AlignmentStats.from_points(p, q).to_array())
        own = {
            "pa": np.full(len(keys), mine, dtype=np.int64),
            "pb": np.array(keys, dtype=np.int64),
            "stats": np.array(rows, dtype=float).reshape(len(keys), 3 + 2 * d + d * d),
            "links": np.ones(len(keys), dtype=np.int64),
        }
        self._cc_begin(level, "align", own)

    # ------------------------------------------------------------------ 6. refinement
    def begin_refine(self, level: int) -> None:
        st = self.levels.get(level)
        if st is None or st.leaf:
            return
        st.active, st.iteration, st.nbr_pose, st.previous = True, 0, {}, None

    def refine_send(self, level: int) -> None:
        st = self.levels.get(level)
        if st is None or not st.active:
            return
        pose = self._pose()
        if st.nbrs:
            self.share_rounds += 1
            self.shares_sent += len(st.nbrs)
        for j in st.nbrs:
            self._send(PoseShare, j, "refine", level=level, group=st.group, phase="refine",
                       iteration=st.iteration, pose=pose)

    def _pose(self) -> np.ndarray:
        return np.concatenate([self.position, self.rotation.ravel()])

    def _star(self, st: LevelState) -> tuple[EnsembleProblem, np.ndarray, np.ndarray] | None:
        nb = [j for j in st.nbrs if j in st.nbr_pose and j in self.z_in]
        if not nb:
            return None
        m, d = len(nb), self.config.dim
        ar = np.arange(1, m + 1)
        i = np.concatenate([np.zeros(m, dtype=np.int64), ar])
        j = np.concatenate([ar, np.zeros(m, dtype=np.int64)])
        z = np.concatenate([np.array([self.z_out[k] for k in nb]), np.array([self.z_in[k] for k in nb])])
        star = EnsembleProblem(d, m + 1, self.config.radius, i, j, z)
        pos = np.concatenate([self.position[None], np.array([st.nbr_pose[k][0] for k in nb])])
        rot = np.concatenate([self.rotation[None], np.array([st.nbr_pose[k][1] for k in nb])])
        return star, pos, rot

    def refine_update(self, level: int) -> None:
        """One local step: measure the own gradient, then move to the best pose given the neighbours."""
        st = self.levels.get(level)
        if st is None or not st.active:
            return
        made = self._star(st)
        st.iteration += 1
        if made is None:
            st.last_grad = 0.0
            return
        star, pos, rot = made
        ori = matrix_to_angle(rot) if self.config.dim == 2 else matrix_to_quat(rot)
        g_pos, _ = gradient(star, pos, ori)
        st.last_grad = float(np.abs(g_pos[0]).max() / self.config.radius)
        # best own orientation for the current centres (closed-form Kabsch, eq. 1 per module)
        R_new = fit_orientations(star, pos)[0]
        m = star.n - 1
        rz_out = np.einsum("ab,mb->ma", R_new, star.z[:m])
        rz_in = np.einsum("mab,mb->ma", rot[1:], star.z[m:])
        # best own centre for the neighbours' poses: mean of c_j - R_i z_ij + R_j z_ji
        target = np.mean(pos[1:] - rz_out + rz_in, axis=0)
        self.rotation = R_new
        # damped local step with heavy-ball momentum (local: uses only the module's own history)
        prev = st.previous if st.previous is not None else self.position
        new = self.position + self.config.step * (target - self.position) + self.config.momentum * (self.position - prev)
        st.previous = self.position
        self.position = new

    def begin_grad(self, level: int) -> None:
        st = self.levels.get(level)
        if st is None or not st.active:
            return
        self._cc_begin(level, "grad", {"g": np.array([st.last_grad])})

    def refining(self, level: int) -> bool:
        st = self.levels.get(level)
        return st is not None and st.active


_NOT_YET = {"__not_yet__": None}
_NOBODY = 2**62  # group id of a level-0 relay before it hears of any candidate


def _step_of(msg: Message) -> str:
    if isinstance(msg, Hello):
        return "neighbor_detection"
    if isinstance(msg, (TreeFlood, Join)):
        return "leader_election"
    if isinstance(msg, ClusterClaim):
        return "graph_abstraction"
    return msg.phase
