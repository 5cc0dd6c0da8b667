"""Pose gossip: every agent's newest consensus pose, carried on the ADMM messages to the neighbours.

A row ``(assembly index, step, round, x, y, z, theta)`` holds an assembly's consensus pose (root frame
of the gauge, Liu et al. 2024 eq. (19) turns two rows into a relative pose) at its latest step, written at
``round``. :class:`PoseGossip` is one agent's table of these rows:

* receive half (:meth:`PoseGossip.merge`): a row replaces the held one only when it is newer by
  ``(step, round)``, so late, duplicated or reordered copies never overwrite newer values, and the
  holder's own row is never taken from others;
* send half (:meth:`PoseGossip.attach`): the table rides on a message to a neighbour only when it
  changed materially (a new row, a new step, or a pose moved by more than ``eps``) since it last
  went to that neighbour, or every ``refresh`` rounds, which repairs a lost copy.

:attr:`PoseGossip.changed` is the last round of a material change; the agent counts the gossip as
settled (:meth:`PoseGossip.settled`) two rounds after it. The agent (:mod:`agents.assembly`) writes
its own row from its consensus (:meth:`PoseGossip.set_own`) or a whole step from a joint solution
(:meth:`PoseGossip.fill`).
"""

from __future__ import annotations

import numpy as np

from decentral.geometry import wrap_angle

__all__ = ["PoseGossip", "pose_row"]


def pose_row(index: int, step: int, round_index: int, R: np.ndarray, p: np.ndarray) -> np.ndarray:
    """The table row ``(index, step, round, x, y, z, theta)`` of a pose ``R`` (2, 2), ``p`` (3,)."""
    return np.array([index, step, round_index, *p, np.arctan2(R[1, 0], R[0, 0])])


class PoseGossip:
    """One agent's gossip table of consensus poses (a row per assembly), with a send and a receive half.

    Parameters
    ----------
    me : int
        The holder's assembly index (its row is written only by :meth:`set_own` and :meth:`fill`).
    n : int
        Number of assemblies (rows naming another index are ignored).
    eps : float
        A pose moved by more than this (m or rad) is a material change.
    refresh : int
        The table goes again to a neighbour after this many rounds even when unchanged.
    """

    def __init__(self, me: int, n: int, eps: float, refresh: int):
        self.me, self.n, self.eps, self.refresh = me, n, eps, refresh
        self.rows: dict[int, np.ndarray] = {}
        self.version = 0  # bumped on every material change
        self.changed = 0  # last round of a material change
        self._sent: dict[str, tuple[int, int]] = {}  # receiver -> (version, round) last sent

    def __bool__(self) -> bool:
        return bool(self.rows)

    def settled(self, round_index: int) -> bool:
        """Whether no material change happened in the last two rounds."""
        return round_index - self.changed >= 2

    def _moved(self, row: np.ndarray, old: np.ndarray) -> float:
        return max(np.abs(row[3:6] - old[3:6]).max(), abs(wrap_angle(row[6] - old[6])))

    def _touch(self, round_index: int) -> None:
        self.version += 1
        self.changed = round_index

    # ------------------------------------------------------------------ own rows
    def set_own(self, row: np.ndarray, round_index: int) -> None:
        """Write the holder's own row (a material change if its step is new or its pose moved by > ``eps``)."""
        old = self.rows.get(self.me)
        if old is None or old[1] != row[1] or self._moved(row, old) > self.eps:
            self._touch(round_index)
        self.rows[self.me] = row

    def fill(self, rows: list[np.ndarray], round_index: int) -> None:
        """Write whole rows known at once (a joint solution's step): always a material change."""
        for row in rows:
            self.rows[int(row[0])] = row
        self._touch(round_index)

    # ------------------------------------------------------------------ receive half
    def merge(self, table, round_index: int) -> None:
        """Take the newer rows of a received table ``(m, 7)`` (``None``: the message carried none)."""
        if table is None:
            return
        for row in np.asarray(table).reshape(-1, 7):
            i = int(row[0])
            if not 0 <= i < self.n or i == self.me:
                continue
            old = self.rows.get(i)
            if old is None or (row[1], row[2]) > (old[1], old[2]):
                self.rows[i] = np.array(row)
                moved = self._moved(row, old) if old is not None else 0
                if old is None or row[1] != old[1] or moved > self.eps:
                    self._touch(round_index)

    # ------------------------------------------------------------------ send half
    def attach(self, receiver: str, round_index: int) -> np.ndarray | None:
        """The table ``(m, 7)`` to put on a message to ``receiver`` now, or ``None`` (unchanged since it last
        went there, and not yet due again)."""
        if not self.rows:
            return None
        version, when = self._sent.get(receiver, (-1, -(10**9)))
        if version == self.version and round_index - when < self.refresh:
            return None
        self._sent[receiver] = (self.version, round_index)
        return np.array([self.rows[i] for i in sorted(self.rows)])
