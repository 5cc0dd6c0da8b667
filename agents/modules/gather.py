"""Convergecast and dissemination along a group's tree, with the group leader's decision in between."""

from __future__ import annotations

import numpy as np

from agents.modules.state import NOT_YET
from protocols.ensemble.aggregation import Convergecast
from protocols.ensemble.messages import Command, Report

__all__ = ["Gather"]


class Gather:
    """Aggregate a step's values up the tree (:class:`Report`), let the leader decide, pass the decision down.

    The phases register what the leader does with a step's total (``leaders[step](level, total)``)
    and what every module does with a decision (``commands[step](level, payload)``).
    """

    def __init__(self, agent):
        self.agent = agent
        self.leaders: dict = {}
        self.commands: dict = {}

    def begin(self, level: int, step: str, own: dict) -> None:
        """Contribute this module's values ``own`` to ``step``."""
        st = self.agent.levels[level]
        early = st.cc.get(step)
        # a child's report may have arrived before this node began the step: keep it
        cc = early[0] if early is not None and early[1] is NOT_YET else Convergecast(step, st.children)
        st.cc[step] = (cc, own)
        self._try(level, step)

    def _try(self, level: int, step: str) -> None:
        a = self.agent
        st = a.levels[level]
        cc, own = st.cc[step]
        if own is None or not cc.complete:
            return
        total = cc.result(own)
        st.cc[step] = (cc, None)  # done: keep the children's reports (the leaf step needs them)
        if st.parent >= 0:
            a.link.send(Report, st.parent, step, level=level, group=st.group, phase=step, payload=total)
        else:
            self.lead(level, step, total)

    def on_report(self, sender: int, msg: Report) -> None:
        st = self.agent.levels.get(msg.level)
        if st is None or st.group != msg.group:
            return
        if msg.phase not in st.cc or st.cc[msg.phase][1] is None:
            st.cc[msg.phase] = (Convergecast(msg.phase, st.children), NOT_YET)
        cc, own = st.cc[msg.phase]
        cc.receive(sender, {k: np.asarray(v) for k, v in msg.payload.items()})
        if own is not NOT_YET:
            self._try(msg.level, msg.phase)

    def on_command(self, sender: int, msg: Command) -> None:
        self.command(msg.level, msg.phase, {k: np.asarray(v) for k, v in msg.payload.items()})

    def lead(self, level: int, step: str, total: dict) -> None:
        """The group leader's decision on a step's total."""
        decide = self.leaders.get(step)
        if decide is not None:
            decide(level, total)

    def command(self, level: int, step: str, payload: dict) -> None:
        """Apply a decision here (and pass it on)."""
        apply = self.commands.get(step)
        if apply is not None:
            apply(level, payload)

    def disseminate(self, level: int, step: str, payload: dict) -> None:
        a = self.agent
        st = a.levels[level]
        for c in sorted(st.children):
            a.link.send(Command, c, step, level=level, group=st.group, phase=step, payload=payload)
