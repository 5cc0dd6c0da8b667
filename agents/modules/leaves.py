"""Phase 4 of a module agent at a leaf: gather the part's observations at its leader, localize, send the poses down."""

from __future__ import annotations

import numpy as np

from decentral.ensemble import EnsembleProblem, refine
from decentral.ensemble.breadth_first import place_breadth_first
from protocols.ensemble.aggregation import split_by_subtree
from protocols.ensemble.messages import Command

__all__ = ["LeafPhase"]


class LeafPhase:
    """A part no larger than the leaf size is localized by its leader with the centralized leaf routine
    (Funiak et al. 2008 Algorithm 1 line 2); each module receives only its subtree's poses."""

    def __init__(self, agent):
        self.agent = agent
        agent.gather.leaders["leaf"] = self.solve
        agent.gather.commands["leaf"] = self.command

    def begin_leaf(self, level: int) -> None:
        a = self.agent
        st = a.levels.get(level)
        if st is None or not st.leaf:
            return
        nb = st.nbrs
        own = {
            "ids": np.array([a.id], dtype=np.int64),
            "oi": np.full(len(nb), a.id, dtype=np.int64),
            "oj": np.array(nb, dtype=np.int64),
            "oz": np.array([a.z_out[j] for j in nb], dtype=float).reshape(len(nb), a.config.dim),
        }
        a.gather.begin(level, "leaf", own)

    def solve(self, level: int, total: dict) -> None:
        """At the part leader: localize the gathered part."""
        cfg = self.agent.config
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
        self.agent.gather.command(level, "leaf", {"ids": ids, "pos": res.position, "rot": res.rotation})

    def command(self, level: int, payload: dict) -> None:
        """Take this module's pose; send each child its subtree's poses."""
        a = self.agent
        st = a.levels[level]
        row = np.flatnonzero(payload["ids"] == a.id)
        if row.size:
            a.position = payload["pos"][row[0]].copy()
            a.rotation = payload["rot"][row[0]].copy()
        cc = st.cc["leaf"][0]
        members = {c: cc.received[c]["ids"] for c in cc.received}
        for c, sub in split_by_subtree(payload["ids"], {"pos": payload["pos"], "rot": payload["rot"]}, members).items():
            a.link.send(Command, c, "leaf", level=level, group=st.group, phase="leaf", payload=sub)
