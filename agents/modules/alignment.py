"""Phase 5 of a module agent: rigid alignment of the parts of a cut (Funiak et al. 2008 Algorithm 1 lines 7-10)."""

from __future__ import annotations

import numpy as np

from decentral.ensemble import AlignmentStats, merge_point_pairs
from protocols.ensemble.leader import plan_merge
from protocols.ensemble.messages import PoseShare

__all__ = ["AlignmentPhase"]


class AlignmentPhase:
    """Modules on the cut exchange poses and aggregate the alignment statistics of their observations
    across it to the group leader, which solves eq. (5) and disseminates one transform per part."""

    def __init__(self, agent):
        self.agent = agent
        agent.gather.leaders["align"] = self.lead
        agent.gather.commands["align"] = self.command

    def begin_boundary(self, level: int) -> None:
        a = self.agent
        st = a.levels.get(level)
        if st is None or st.leaf or level + 1 not in a.levels:
            return
        mine = a.levels[level + 1].group
        for j in st.nbrs:
            if st.nbr_next.get(j, mine) != mine:
                a.link.send(PoseShare, j, "boundary", level=level, group=st.group, phase="boundary", iteration=0,
                            pose=a.pose())

    def begin_align(self, level: int) -> None:
        a = self.agent
        st = a.levels.get(level)
        if st is None or st.leaf or level + 1 not in a.levels:
            return
        mine = a.levels[level + 1].group
        d = a.config.dim
        keys, rows = [], []
        for j, (pj, rj) in sorted(st.boundary.items()):
            # Algorithm 1 lines 7-8 for the observation pair across the cut, via the centralized routine
            p, q = merge_point_pairs(a.position[None], a.rotation[None], pj[None], rj[None],
                                     a.z_out[j][None], a.z_in[j][None])
            keys.append(st.nbr_next[j])
            rows.append(AlignmentStats.from_points(p, q).to_array())
        own = {
            "pa": np.full(len(keys), mine, dtype=np.int64),
            "pb": np.array(keys, dtype=np.int64),
            "stats": np.array(rows, dtype=float).reshape(len(keys), 3 + 2 * d + d * d),
            "links": np.ones(len(keys), dtype=np.int64),
        }
        a.gather.begin(level, "align", own)

    def lead(self, level: int, total: dict) -> None:
        """At the group leader: one rigid transform per part."""
        plan = self.agent.levels[level].plan
        T = plan_merge(plan.part_leader, plan.part_size, total["pa"], total["pb"], total["stats"], total["links"])
        parts = np.array(sorted(T), dtype=np.int64)
        self.agent.gather.command(level, "align", {
            "parts": parts,
            "R": np.stack([T[int(p)].R for p in parts]),
            "t": np.stack([T[int(p)].t for p in parts]),
        })

    def command(self, level: int, payload: dict) -> None:
        a = self.agent
        mine = a.levels[level + 1].group
        k = int(np.flatnonzero(payload["parts"] == mine)[0])
        R, t = payload["R"][k], payload["t"][k]
        # Algorithm 1 line 10: x_B <- R x_B + t
        a.position = R @ a.position + t
        a.rotation = R @ a.rotation
        a.gather.disseminate(level, "align", payload)
