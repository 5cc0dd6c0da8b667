"""Configuration gossip: who owns which node, from the announcements heard, and the agent's own announcements.

Observers name the owner of a node they detect (and its centre ``q`` in the owner's root frame, seed
000 eq. (4)) from the ``admm.config`` announcements they receive: the owner's own, or a relay by an
agent that holds it (:class:`protocols.admm_messages.ConfigAnnounce`, ``owner`` field). A relayed copy
never replaces what the owner said itself for the same step; a configuration holds from its step on,
the latest one not after a step applies to it. :class:`ConfigTable` keeps them and answers the
relays an ``admm.config_request`` asks for (the receive half). :class:`ConfigGossip` is the whole
role: it announces the agent's own configuration (a broadcast when it changes, every
``announce_every`` steps a unicast to the current observers), answers requests, and asks for the
nodes the agent sees but cannot name; the agent (:mod:`agents.assembly`) moves the messages.
"""

from __future__ import annotations

import numpy as np

from protocols.admm_messages import ConfigAnnounce, ConfigRequest
from protocols.messages import BROADCAST

__all__ = ["ConfigTable", "ConfigGossip"]

_NEVER = -(10**9)


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

    def owners_of(self, node: int, step: int) -> list[tuple[str, np.ndarray]]:
        """Every assembly that lists ``node`` at ``step``, with the centre (3,) it gives, in name order.

        Two or more means a member lies about its nodes (the centralized reader refuses such a log:
        "node id 4 also belongs to A1"); an observer cannot tell which from the announcements alone,
        so it attributes the detection to each claimant and the consistency test of the joint
        window (:func:`decentral.consistency.screen_members`) finds the member whose data the
        others contradict.
        """
        out = []
        for name in sorted(self.history):
            hist = self.history[name]
            usable = [h for h in hist if h[0] <= step] or hist[:1]
            if usable and node in usable[-1][1]:
                out.append((name, usable[-1][1][node]))
        return out

    def contested(self, step: int) -> dict[int, tuple[str, ...]]:
        """Node ids more than one assembly lists at ``step``: node -> the claimants, in name order."""
        claims: dict[int, list[str]] = {}
        for name in sorted(self.history):
            hist = self.history[name]
            usable = [h for h in hist if h[0] <= step] or hist[:1]
            for node in (usable[-1][1] if usable else {}):
                claims.setdefault(int(node), []).append(name)
        return {node: tuple(names) for node, names in claims.items() if len(names) > 1}

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


class ConfigGossip:
    """One agent's configuration gossip: its own announcements and requests (send half), others' table (receive half).

    Parameters
    ----------
    me : str
        The agent's assembly.
    known : sequence of str
        Every assembly's name.
    announce_every : int
        Re-announce an unchanged configuration to the current observers every this many steps (repairs
        lost announcements).

    Attributes
    ----------
    table : ConfigTable
        Others' configurations.
    own : dict
        Own node id -> centre (3,) in the root frame, at the current step.
    unknown : set of int
        Nodes the agent detects that no configuration held here lists (set by the agent).
    """

    def __init__(self, me: str, known, announce_every: int):
        self.me, self.names, self.announce_every = me, tuple(known), announce_every
        self.table = ConfigTable(me, known)
        self.own: dict[int, np.ndarray] = {}
        self.unknown: set[int] = set()
        self._announced: tuple[int, dict] | None = None  # (step, config) last announced
        self._reannounced = _NEVER  # step of the last re-announcement to the observers
        self._requested = _NEVER  # round of the last request

    def __len__(self) -> int:
        return len(self.table)

    def __contains__(self, name: str) -> bool:
        return name in self.table

    def learn(self, message: ConfigAnnounce) -> bool:
        """Take an announcement (own or relayed); whether the table changed."""
        return self.table.learn(message)

    def owner_of(self, node: int, step: int) -> tuple[str, np.ndarray] | None:
        """The assembly that lists ``node`` at ``step`` and the node's centre (3,), or ``None``."""
        return self.table.owner_of(node, step)

    def owners_of(self, node: int, step: int) -> list[tuple[str, np.ndarray]]:
        """Every assembly that lists ``node`` at ``step`` (:meth:`ConfigTable.owners_of`)."""
        return self.table.owners_of(node, step)

    def set_own(self, config: dict, step: int, round_index: int, observers) -> list[ConfigAnnounce]:
        """The own configuration at ``step``; the announcements due: a broadcast when it changed (rare:
        reconfiguration), else every ``announce_every`` steps one to each of the current ``observers``
        (others ask with a request)."""
        self.own = {int(k): np.asarray(v, float) for k, v in config.items()}
        if self._announced is None or not _same_config(self._announced[1], self.own):
            out = [self.announcement(BROADCAST, step, round_index)]
            self._announced = (step, dict(self.own))
            self._reannounced = step
            return out
        if step - self._reannounced >= self.announce_every:
            out = [self.announcement(observer, step, round_index) for observer in observers]
            self._reannounced = step
            return out
        return []

    def announcement(self, receiver: str, step: int, round_index: int) -> ConfigAnnounce:
        """The own configuration to ``receiver`` (a unicast names the step it was last broadcast at)."""
        ids = np.array(sorted(self.own), dtype=np.int64)
        centres = np.array([self.own[i] for i in ids]).reshape(-1, 3)
        if self._announced is not None and receiver != BROADCAST:
            step = self._announced[0]
        return ConfigAnnounce(sender=self.me, receiver=receiver, round=round_index, step=step, ids=ids,
                              centres=centres)

    def answer(self, request: ConfigRequest, step: int | None, round_index: int) -> list[ConfigAnnounce]:
        """Answers to a request: the own configuration (every agent answers, owner or not: a requester that
        holds every assembly's configuration knows that the ids none of them lists are stray tags), and
        the configurations held here that list a requested node."""
        out = []
        if step is not None and request.sender != self.me:
            out.append(self.announcement(request.sender, step, round_index))
        return out + self.table.relays(request, self.me, round_index)

    def unresolved(self, alive: set[int] | None) -> set[int]:
        """Unnamed nodes that an assembly whose configuration has not arrived here may still own.

        Once every other assembly's configuration is in (announcements, answers to ``config_request``,
        relays), a node none of them lists is a stray tag (docs/formats.md: skipped): it neither holds the
        convergence flag nor triggers requests. Until then an unnamed node may be a pair still to
        come, and an agent that reported convergence without it would report the joint solution of
        a view graph that lacks the pair (4-ring at 50 % loss: 20 mm off, flagged converged).
        ``alive``: the indices of the agents heard from lately (``None``: every agent); a peer not
        heard from for two windows (down, or never started) cannot name its nodes, so once every live
        assembly's configuration is in, the nodes left are its own or stray tags, skipped alike.
        """
        if len(self.table) >= len(self.names) - 1:
            return set()
        if alive is not None and all(self.names[i] in self.table for i in alive if self.names[i] != self.me):
            return set()
        return set(self.unknown)

    def request(self, round_index: int, alive: set[int] | None, every: int = 3) -> list[ConfigRequest]:
        """A broadcast request for the unresolved nodes, at most once in ``every`` rounds (the agent passes a
        round trip at the lag it measured, at least 3: asking again before the answers could have come
        only multiplies the answers, one from every agent)."""
        if not self.unresolved(alive) or round_index - self._requested < max(1, int(every)):
            return []
        self._requested = round_index
        return [ConfigRequest(sender=self.me, receiver=BROADCAST, round=round_index,
                              ids=np.array(sorted(self.unknown), dtype=np.int64))]


def _same_config(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)
