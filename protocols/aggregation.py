"""Tree aggregation: a convergecast of per-agent records up a spanning tree and a broadcast back down.

The transport-free half of the aggregation protocol the assembly agents use to share their cost
forms every window (:mod:`agents.assembly`): which neighbour is an agent's parent, and per window
which records it holds, which it still owes its parent, when the bundle up is due, when to resend it
and whom to send the bundle down to. The agent moves the messages
(:class:`protocols.admm_messages.FormBundle`); nothing here sends, receives or reads a clock, rounds
are passed in.

**Tree.** Every agent knows its hop count to the root (the reference agent, hop 0) as a distance
vector over its view-graph neighbours, ``hop = 1 + min(neighbour hops)``, carried on the messages it
exchanges with them anyway and repaired every round. Its parent is the neighbour with the smallest
hop (ties: smallest index) (:func:`choose_parent`). Hops learnt from a growing set of neighbours only
decrease, and a parent's hop is below its child's when chosen, so parent pointers never form a loop in
a fixed graph; a hop at or above the number of agents means no route (a partition side without the
root counts up to it and stops).

**Per window** (:class:`TreeAggregation`): an agent holds its own record and sends its parent ONE
bundle with it and the records of its children (neighbours that named it as their parent), once
every child it expects has reported or after ``wait`` rounds; records that come later go up as an
update (only the ones not sent yet). The root, holding every agent's record (or on the caller's
timeout), sends the full set down to its children, who forward it to theirs.

**Loss.** A parent acknowledges every bundle from below (with the list of records it holds); a child
resends everything it forwards every ``ack_every`` rounds until acknowledged, so a lost bundle up costs
a few rounds on its own hop rather than a round trip to the root. Once acknowledged it waits
``down_every`` rounds (about the tree's depth) for the down bundle, then sends again; an agent that
has finished the window answers a bundle from below with the down bundle (a lost down bundle is
repaired that way). The down bundle needs no acknowledgement of its own. (Measured on 4 agents at 30 %
loss, relying on the down bundle as the only acknowledgement took 180-200 rounds per window: every
repair waited a whole round trip.)

Message counts per agent and window without loss: one bundle up (plus one update per late child at
most), and per child one acknowledgement and one bundle down, i.e. at most ``1 + 3 * children``
(plus the updates), independent of the number of agents.
"""

from __future__ import annotations

from typing import Any, Callable, Iterable, Mapping

__all__ = ["choose_parent", "tree_from_edges", "TreeAggregation", "DownRepair", "NeighbourTree"]


def choose_parent(neighbour_hops: Mapping[int, int], limit: int) -> tuple[int | None, int | None]:
    """Parent and own hop count from the neighbours' hop counts to the root (distance vector).

    Parameters
    ----------
    neighbour_hops : Mapping[int, int]
        Neighbour index -> its hop count to the root (only neighbours heard from recently).
    limit : int
        Hop counts at or above this mean no route (the number of agents).

    Returns
    -------
    parent, hop : int or None
        The neighbour with the smallest hop (ties: smallest index) and ``1 +`` its hop; ``(None,
        None)`` when no neighbour has a route shorter than ``limit - 1``.
    """
    usable = [(h, i) for i, h in neighbour_hops.items() if 0 <= h < limit - 1]
    if not usable:
        return None, None
    hop, parent = min(usable)
    return parent, hop + 1


def tree_from_edges(edges, total: int, root: int) -> tuple[dict[int, int], dict[int, int]]:
    """Hop counts and parents of every agent from a known graph (what the distance vector converges to).

    Agents that hold every agent's cost forms know the window's whole view graph (each pair form
    names an observer and its target), so they can fill their neighbours' distance-vector entries at
    once instead of waiting for them to cross the graph.

    Parameters
    ----------
    edges : iterable of (int, int)
        Undirected edges (agent indices); self-loops are ignored.
    total : int
        Number of agents.
    root : int
        The root's index.

    Returns
    -------
    hops, parents : dict
        Index -> hop count to the root, and index -> parent (the neighbour with the smallest hop, ties:
        smallest index, as :func:`choose_parent`), for the agents connected to the root.
    """
    adjacent: dict[int, set[int]] = {}
    for a, b in edges:
        if a != b and 0 <= a < total and 0 <= b < total:
            adjacent.setdefault(a, set()).add(b)
            adjacent.setdefault(b, set()).add(a)
    hops, frontier = {root: 0}, [root]
    while frontier:
        nxt = []
        for a in frontier:
            for b in sorted(adjacent.get(a, ())):
                if b not in hops:
                    hops[b] = hops[a] + 1
                    nxt.append(b)
        frontier = nxt
    parents = {a: min((hops[b], b) for b in adjacent[a] if b in hops)[1] for a in hops if a != root}
    return hops, parents


class TreeAggregation:
    """One agent's bookkeeping of one window's convergecast (up) and broadcast (down) of records.

    Parameters
    ----------
    me : int
        Own index (into the agents' common list).
    total : int
        Number of agents (a complete set holds a record of each).
    root : bool
        Whether this agent is the root (it sends down instead of up).
    parent : int or None
        Its parent (None for the root, or when the agent has no route: then it only collects).
    children : iterable of int
        Neighbours expected to send it their bundles (those that named it as their parent).
    start : int
        Round at which the window started.
    wait : int
        Rounds to wait for expected children before sending up what it has.
    hop : int
        Own hop count to the root (0 at the root).
    expected : iterable of int, optional
        The agents whose records make the set complete (default: all ``total``); an agent leaves out
        the ones it has not heard from lately (a peer that is down or never started), so that the
        others' windows still complete.

    Attributes
    ----------
    records : dict
        Agent index -> its record (opaque to this class), every record held, however it came.
    final : bool
        The down bundle has arrived (at the root: it has been sent).
    depth : int
        Largest hop count reported from below (the root uses it to say when the agents start).
    """

    def __init__(self, me: int, total: int, *, root: bool, parent: int | None, children: Iterable[int] = (),
                 start: int = 0, wait: int = 6, hop: int = 0, expected: Iterable[int] | None = None):
        self.me, self.total, self.root, self.parent = me, total, root, parent
        self.expected = None if expected is None else frozenset(expected) | {me}
        self.children = set(children)
        self.start, self.wait, self.hop = start, wait, hop
        self.records: dict[int, Any] = {}
        self.final = False
        self.depth = hop
        self._forward: set[int] = set()  # own and children's records: the ones that go up
        self._sent_up: set[int] = set()
        self._reported: set[int] = set()  # children heard from this window
        self._last_up: int | None = None
        self._acked: int | None = None  # round of the parent's acknowledgement of everything sent up
        self.unanswered = 0  # bundles up in a row that the parent has not acknowledged

    @property
    def complete(self) -> bool:
        """Whether it holds a record of every expected agent (default: of every agent)."""
        if self.expected is None:
            return len(self.records) == self.total
        return self.expected.issubset(self.records)

    def expect(self, member: int) -> None:
        """Wait for ``member``'s record too (an agent given up on at the window's start was heard again)."""
        if self.expected is not None and 0 <= member < self.total:
            self.expected = self.expected | {member}

    @property
    def sent_up(self) -> bool:
        """Whether a bundle has gone up this window."""
        return self._last_up is not None

    def add(self, records: Mapping[int, Any], *, child: int | None = None, forward: bool = False,
            depth: int | None = None) -> set[int]:
        """Merge records (known ones are kept) and return the indices that were new.

        ``child``: they came up from this child (it has reported, and they go up from here too);
        ``forward``: they go up from here (own record); ``depth``: the sender's reported depth.
        """
        new = {i for i in records if 0 <= i < self.total and i not in self.records}
        for i in new:
            self.records[i] = records[i]
        if child is not None:
            self._reported.add(child)
            self.children.add(child)
        if child is not None or forward:
            self._forward |= {i for i in records if i in self.records}
        if depth is not None:
            self.depth = max(self.depth, depth)
        return new

    def up_due(self, round_index: int) -> bool:
        """Whether records are owed to the parent now (own record in, children reported or waited out)."""
        if self.root or self.parent is None or self.final or self.me not in self._forward:
            return False
        if not self._forward - self._sent_up:
            return False
        return self.children <= self._reported or round_index - self.start >= self.wait

    def take_up(self, round_index: int) -> list[int]:
        """The records owed to the parent (marked as sent, awaiting the parent's acknowledgement)."""
        out = sorted(self._forward - self._sent_up)
        self._sent_up |= set(out)
        self._last_up = round_index
        self._acked = None
        self.unanswered += 1
        return out

    def acknowledge(self, have: Iterable[int], round_index: int) -> None:
        """The parent holds the records ``have``: acknowledged if that covers everything sent up."""
        if self._sent_up <= set(have):
            self._acked = round_index
            self.unanswered = 0

    @property
    def acknowledged(self) -> bool:
        """Whether the parent has acknowledged everything sent up."""
        return self._acked is not None

    def resend_due(self, round_index: int, ack_every: int, down_every: int) -> bool:
        """Send everything up again: no acknowledgement ``ack_every`` rounds after the last bundle up, or
        no down bundle ``down_every`` rounds after the acknowledgement."""
        if self.root or self.parent is None or self.final or self._last_up is None:
            return False
        if self._acked is None:
            return round_index - self._last_up >= ack_every
        return round_index - max(self._acked, self._last_up) >= down_every

    def take_resend(self, round_index: int) -> list[int]:
        """Every record that goes up from here (for a resend)."""
        self._last_up = round_index
        self._sent_up |= self._forward
        if self._acked is None:
            self.unanswered += 1
        return sorted(self._forward)

    def missing_from(self, members: Iterable[int]) -> list[int]:
        """Records that go up from here but are not among ``members`` (a partial down bundle lacks them)."""
        return sorted(self._forward - set(members))

    def down_targets(self, exclude: Iterable[int] = ()) -> list[int]:
        """Children to send the down bundle to (expected ones and those that reported), sorted."""
        return sorted(self.children - set(exclude) - {self.me})


class DownRepair:
    """The children still owed a window's down bundle, and when to send it to them again.

    A child that has the down bundle says so (an acknowledgement, :meth:`have`) or starts the ADMM at the
    bundle's ``start`` round and is heard from about a round later; a child still silent ``grace`` rounds
    after ``start`` gets the bundle again, every ``every`` rounds, at most ``tries`` times (it may no longer
    be a neighbour; it also asks by itself). Rounds are passed in; nothing here sends.

    Parameters
    ----------
    children : iterable of int
        The children the down bundle went to at ``round_index``.
    start : int
        The round at which the ADMM of the window starts everywhere.
    round_index : int
        The round of the first sending.
    """

    def __init__(self, children: Iterable[int], start: int, round_index: int, *, every: int = 3, tries: int = 4,
                 grace: int = 2):
        self.start, self.every, self.tries, self.grace = start, every, tries, grace
        self.pending: dict[int, tuple[int, int]] = {c: (round_index, 0) for c in children}  # -> (last sent, resends)

    def __bool__(self) -> bool:
        return bool(self.pending)

    def have(self, child: int | None) -> None:
        """``child`` has the down bundle (it acknowledged it): never resent."""
        self.pending.pop(child, None)

    def due(self, round_index: int, heard: Callable[[int], bool]) -> list[int]:
        """Children to send the down bundle again now (sorted), counted as sent; those ``heard`` from in the
        window's ADMM are dropped (they have it)."""
        out = []
        for child, (last, tries) in sorted(self.pending.items()):
            if heard(child):
                del self.pending[child]
            elif round_index >= max(self.start + self.grace, last + self.every) and tries < self.tries:
                self.pending[child] = (round_index, tries + 1)
                out.append(child)
        return out


class NeighbourTree:
    """The distance vector an agent keeps: each neighbour's hop count to the root and parent, as last heard.

    Entries come from the ``tree`` block of the neighbours' ADMM values and from the bundles they send
    (:meth:`heard`), or all at once from a window's whole view graph (:meth:`learn`). An entry is
    trusted while it is recent (:meth:`fresh`); the agent's own parent and hop follow from the trusted
    entries (:meth:`position`, :func:`choose_parent`). Rounds and steps are passed in.

    Parameters
    ----------
    names : sequence of str
        Every agent's name (indices are positions in it).
    me, root : int
        Own index and the root's (the reference agent).
    fresh_rounds : int
        Rounds for which an entry is trusted (besides entries heard in this window or the one before).

    Attributes
    ----------
    entries : dict
        Neighbour name -> ``(hop, parent index, round heard, step heard)`` (parent -1: none).
    """

    def __init__(self, names, me: int, root: int, fresh_rounds: int):
        self.names = tuple(names)
        self.index = {name: i for i, name in enumerate(self.names)}
        self.me, self.root, self.fresh_rounds = me, root, fresh_rounds
        self.entries: dict[str, tuple[int, int, int, int | None]] = {}
        self.graph_depth = 0  # the tree's depth in the last whole view graph learnt (0: none yet)

    def heard(self, neighbour: str, hop: int, parent: int, round_index: int, step: int | None) -> None:
        """``neighbour`` says it is ``hop`` hops from the root, below ``parent`` (heard at this round and step)."""
        self.entries[neighbour] = (hop, parent, round_index, step)

    def drop(self, neighbour: str) -> None:
        """Forget ``neighbour``'s entry (a parent that stayed silent: choose again)."""
        self.entries.pop(neighbour, None)

    def fresh(self, entry: tuple, round_index: int, step: int | None) -> bool:
        """Whether an entry is recent: heard within ``fresh_rounds`` rounds, or in this window or the one
        before (rounds between windows depend on the pace of the sensor steps, which a process does not
        choose)."""
        return round_index - entry[2] <= self.fresh_rounds or entry[3] is not None and entry[3] >= (step or 0) - 1

    def position(self, round_index: int, step: int | None) -> tuple[int | None, int | None]:
        """(parent index, hop count to the root) from the recent entries (distance vector)."""
        if self.me == self.root:
            return None, 0
        hops = {self.index[a]: entry[0] for a, entry in self.entries.items() if self.fresh(entry, round_index, step)}
        return choose_parent(hops, len(self.names))

    def children(self, round_index: int, step: int | None) -> set[int]:
        """Neighbours whose recent entry names this agent as their parent."""
        return {self.index[a] for a, entry in self.entries.items()
                if entry[1] == self.me and self.fresh(entry, round_index, step)}

    def learn(self, edges, round_index: int, step: int | None) -> None:
        """Replace the entries with the places the whole view graph ``edges`` (index pairs) gives the neighbours.

        Assemblies no longer adjacent leave the table (with no ADMM values to refresh it, a stale entry
        would make a former neighbour wait for a child that never reports)."""
        hops, parents = tree_from_edges(edges, len(self.names), self.root)
        self.graph_depth = max(hops.values(), default=0)
        self.entries = {}
        for a, b in edges:
            other = b if a == self.me else a if b == self.me else None
            if other is not None and other != self.me and other in hops:
                self.entries[self.names[other]] = (hops[other], parents.get(other, -1), round_index, step)
