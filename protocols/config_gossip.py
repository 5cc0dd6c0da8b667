"""The receive half of configuration gossip: who owns which node, from the announcements heard.

Observers name the owner of a node they detect (and its centre ``q`` in the owner's root frame, seed
000 eq. (4)) from the ``admm.config`` announcements they receive: the owner's own, or a relay by an
agent that holds it (:class:`protocols.admm_messages.ConfigAnnounce`, ``owner`` field). A relayed copy
never replaces what the owner said itself for the same step; a configuration holds from its step on,
the latest one not after a step applies to it. :class:`ConfigTable` keeps them and answers the
relays an ``admm.config_request`` asks for; the agent (:mod:`agents.assembly`) sends and receives.
"""

from __future__ import annotations

import numpy as np

from protocols.admm_messages import ConfigAnnounce, ConfigRequest

__all__ = ["ConfigTable"]


class ConfigTable:
    """Other assemblies' configurations: name -> ``[(step, {node: centre (3,)})]`` sorted by step.

    Parameters
    ----------
    me : str
        The holder's own assembly (its own configuration is not kept here).
    known : iterable of str
        Every assembly's name (announcements for others are ignored).
    """

    def __init__(self, me: str, known):
        self.me = me
        self.known = frozenset(known)
        self.history: dict[str, list[tuple[int, dict]]] = {}

    def __len__(self) -> int:
        return len(self.history)

    def __contains__(self, name: str) -> bool:
        return name in self.history

    def __getitem__(self, name: str) -> list[tuple[int, dict]]:
        return self.history[name]

    def learn(self, message: ConfigAnnounce) -> bool:
        """Take an announcement (own or relayed); whether the table changed."""
        owner = message.owner or message.sender
        if owner == self.me or owner not in self.known:
            return False
        hist = self.history.get(owner, [])
        if message.owner and any(step == message.step for step, _ in hist):
            return False  # a relayed copy never replaces what the owner said itself
        entry = (message.step, {int(i): np.array(c) for i, c in zip(message.ids, message.centres)})
        self.history[owner] = sorted([h for h in hist if h[0] != message.step] + [entry], key=lambda h: h[0])
        return True

    def owner_of(self, node: int, step: int) -> tuple[str, np.ndarray] | None:
        """The assembly that lists ``node`` at ``step`` and the node's centre (3,), or ``None``."""
        for name, hist in self.history.items():
            usable = [h for h in hist if h[0] <= step] or hist[:1]
            conf = usable[-1][1]
            if node in conf:
                return name, conf[node]
        return None

    def relays(self, request: ConfigRequest, sender: str, round_index: int) -> list[ConfigAnnounce]:
        """Answers to ``request`` from ``sender``: the configurations held here that list a requested node
        (the owner's own answer and the request each cross one lossy link; every relay is another chance)."""
        ids = {int(i) for i in request.ids}
        out = []
        for owner, hist in sorted(self.history.items()):
            if owner == request.sender or not hist:
                continue
            step, conf = hist[-1]
            if ids & set(conf):
                keys = np.array(sorted(conf), dtype=np.int64)
                out.append(ConfigAnnounce(sender=sender, receiver=request.sender, round=round_index, step=step,
                                          ids=keys, centres=np.array([conf[int(i)] for i in keys]).reshape(-1, 3),
                                          owner=owner))
        return out
