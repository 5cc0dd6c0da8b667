"""Phases 3-4 of a module agent: the group's size, its abstract graph of clusters, and the normalized cut."""

from __future__ import annotations

import numpy as np

from agents.modules.state import LevelState
from protocols.ensemble.leader import CutPlan, cut_clusters
from protocols.ensemble.messages import ClusterClaim

__all__ = ["AbstractionPhase"]


class AbstractionPhase:
    """Count the group; cluster it (self-elected leaders, nearest by hops); cut the abstract graph.

    Modules elect themselves cluster leaders with a small probability and join the nearest one by
    hop count (ties to the smaller leader id); the abstract graph is aggregated to the group leader
    (one module per cluster when the group is small: the exact cut), which cuts it (Funiak et al.
    2008 eq. (4)) and disseminates the parts, their leaders and sizes. A part no larger than the leaf
    size is a leaf.
    """

    def __init__(self, agent):
        self.agent = agent
        gather = agent.gather
        gather.leaders.update({"count": self.lead_count, "abstract": self.lead_abstract})
        gather.commands.update({"count": self.command_count, "cut": self.command_cut})

    def begin_count(self) -> None:
        self.agent.gather.begin(0, "count", {"size": np.array([1], dtype=np.int64)})

    def lead_count(self, level: int, total: dict) -> None:
        st = self.agent.levels[level]
        st.size = int(total["size"][0])
        self.agent.gather.command(level, "count", {"size": total["size"]})

    def command_count(self, level: int, payload: dict) -> None:
        a = self.agent
        st = a.levels[level]
        st.size = int(payload["size"][0])
        st.leaf = st.size <= a.config.hierarchy.leaf_size
        a.gather.disseminate(level, "count", payload)

    def begin_cluster(self, level: int) -> None:
        a = self.agent
        st = a.levels.get(level)
        if st is None or st.leaf:
            return
        h = a.config.hierarchy
        exact = h.cut == "exact" or st.size <= 4 * h.abstract_size
        if exact:  # one module per cluster: the exact normalized cut
            st.cluster = a.id
            st.nbr_cluster = {j: j for j in st.nbrs}
            return
        p = min(1.0, h.abstract_size / max(st.size, 1))
        if a.id == st.group or a.rng.random() < p:
            st.cluster = a.id
            for j in st.nbrs:
                a.link.send(ClusterClaim, j, "graph_abstraction", level=level, group=st.group, leader=a.id, hops=1)

    def on_claim(self, sender: int, msg: ClusterClaim) -> None:
        st = self.agent.levels.get(msg.level)
        if st is not None and st.group == msg.group:
            st.nbr_cluster[sender] = msg.leader
            st.cluster_in.append((msg.hops, msg.leader))

    def decide_cluster(self, level: int, st: LevelState) -> None:
        """End of a round: join the nearest cluster leader heard and tell the neighbours."""
        arrivals, st.cluster_in = st.cluster_in, []
        if st.cluster >= 0:
            return
        hops, leader = min(arrivals)
        st.cluster = leader
        for j in st.nbrs:
            self.agent.link.send(ClusterClaim, j, "graph_abstraction", level=level, group=st.group, leader=leader,
                                 hops=hops + 1)

    def begin_abstract(self, level: int) -> None:
        a = self.agent
        st = a.levels.get(level)
        if st is None or st.leaf:
            return
        nb = [j for j in st.nbrs if j in st.nbr_cluster]
        own = {
            "ea": np.full(len(nb), st.cluster, dtype=np.int64),
            "eb": np.array([st.nbr_cluster[j] for j in nb], dtype=np.int64),
            "ew": np.ones(len(nb), dtype=np.int64),
            "cid": np.array([st.cluster], dtype=np.int64),
            "csize": np.array([1], dtype=np.int64),
            "cmin": np.array([a.id], dtype=np.int64),
        }
        a.gather.begin(level, "abstract", own)

    def lead_abstract(self, level: int, total: dict) -> None:
        a = self.agent
        st = a.levels[level]
        cid = total["cid"]
        if cid.size < 2:  # a single cluster cannot be cut: localize the group as one leaf
            a.events.append(f"level {level} group {st.group}: one cluster, solved as a leaf")
            plan = CutPlan(cid, np.zeros(1, dtype=np.int64), np.array([a.id]), np.array([st.size]), 0.0)
        else:
            # Funiak et al. 2008 eq. (4) on the aggregated abstract graph (Algorithm 1 line 4)
            plan = cut_clusters(total["ea"], total["eb"], total["ew"], cid, total["csize"], total["cmin"])
        st.plan = plan
        a.gather.command(level, "cut", {
            "cluster_ids": plan.cluster_ids, "cluster_part": plan.cluster_part,
            "part_leader": plan.part_leader, "part_size": plan.part_size,
            "single": np.array([cid.size < 2]),
        })

    def command_cut(self, level: int, payload: dict) -> None:
        a = self.agent
        st = a.levels[level]
        ids = payload["cluster_ids"]
        k = int(np.searchsorted(ids, st.cluster))
        part = int(payload["cluster_part"][k]) if k < ids.size and ids[k] == st.cluster else 0
        nxt = LevelState(int(payload["part_leader"][part]), int(payload["part_size"][part]))
        nxt.leaf = bool(payload["single"][0]) or nxt.size <= a.config.hierarchy.leaf_size
        a.levels[level + 1] = nxt
        a.gather.disseminate(level, "cut", payload)
