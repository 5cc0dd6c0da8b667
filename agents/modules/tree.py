"""Phases 1-2 of a module agent: neighbour detection, leader election by flooding, and the group's spanning tree."""

from __future__ import annotations

import numpy as np

from agents.modules.state import NOBODY
from protocols.ensemble.messages import Hello, Join, TreeFlood

__all__ = ["TreePhase"]


class TreePhase:
    """Tell each neighbour its observation; elect each group's leader and build its tree.

    At level 0 the smallest id floods the whole ensemble (min-id election; the flood's shortest-path
    tree is the group tree); below, the leader named by the parent group floods its part. Every module
    then registers with its parent (:class:`Join`).
    """

    def __init__(self, agent):
        self.agent = agent

    def begin_hello(self) -> None:
        a = self.agent
        for j, zz in a.z_out.items():
            a.link.send(Hello, j, "neighbor_detection", z=zz)

    def on_hello(self, sender: int, msg: Hello) -> None:
        self.agent.z_in[sender] = np.asarray(msg.z, float)

    def begin_election(self) -> None:
        """Level 0: every module is a candidate; the smallest id wins by flooding."""
        a = self.agent
        st = a.level_state(0)
        st.nbrs = sorted(a.z_out)
        st.hops, st.parent, st.joined = 0, -1, True
        if st.nbrs and min(st.nbrs) < a.id:
            # a neighbour has a smaller id, so this module cannot win: it only relays (fewer floods)
            st.group = NOBODY
            return
        st.group = a.id
        for j in st.nbrs:
            a.link.send(TreeFlood, j, "leader_election", level=0, group=a.id, hops=0)

    def begin_tree(self, level: int) -> None:
        """Below level 0 the part leader (named by the parent group) floods its part."""
        a = self.agent
        st = a.levels.get(level)
        if st is None or st.group != a.id:
            return
        st.hops, st.parent, st.joined = 0, -1, True
        for j in a.levels[level - 1].nbrs:
            a.link.send(TreeFlood, j, "leader_election", level=level, group=a.id, hops=0)

    def on_flood(self, sender: int, msg: TreeFlood) -> None:
        a = self.agent
        level = msg.level
        if level > 0:
            above = a.levels.get(level - 1)
            if above is not None:
                above.nbr_next[sender] = msg.group
            st = a.levels.get(level)
            if st is None or st.group != msg.group:
                return
            st.flood_in.append((msg.hops + 1, sender, msg.group))
        else:
            st = a.level_state(0)
            st.flood_in.append((msg.hops + 1, sender, msg.group))

    def decide_flood(self, level: int, st) -> None:
        """End of a round: adopt the best flood heard and pass it on."""
        a = self.agent
        arrivals, st.flood_in = st.flood_in, []
        if level == 0:
            # min-id election: adopt a smaller group id, or the same id by a shorter path
            hops, sender, group = min(arrivals, key=lambda x: (x[2], x[0], x[1]))
            if (group, hops) < (st.group, st.hops):
                st.group, st.hops, st.parent = group, hops, sender
                for j in st.nbrs:
                    a.link.send(TreeFlood, j, "leader_election", level=0, group=group, hops=hops)
            return
        if st.joined:
            return
        hops, sender, group = min(arrivals)
        st.hops, st.parent, st.joined = hops, sender, True
        for j in a.levels[level - 1].nbrs:
            a.link.send(TreeFlood, j, "leader_election", level=level, group=group, hops=hops)

    def begin_join(self, level: int) -> None:
        """After the flood has settled: register with the parent; learn the same-group neighbours."""
        a = self.agent
        st = a.levels.get(level)
        if st is None:
            return
        if level > 0:
            above = a.levels[level - 1]
            st.nbrs = sorted(j for j in above.nbrs if above.nbr_next.get(j) == st.group)
        if st.parent >= 0:
            a.link.send(Join, st.parent, "leader_election", level=level, group=st.group)

    def on_join(self, sender: int, msg: Join) -> None:
        self.agent.level_state(msg.level).children.add(sender)
