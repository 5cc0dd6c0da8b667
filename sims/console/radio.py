"""The operator swarm's radio traffic through the simulated network's batched path.

At 50 robots every step broadcasts some 25 odometry reports to 49 peers each: over a thousand
copies, which the network's per-message path books, draws and queues one Python call at a time (most
of a step's CPU). :class:`BatchedRadio` hands each phase's messages to
:meth:`protocols.network.SimulatedNetwork.send_many` in one call per message kind and collects what
arrived with one ``poll_many``: the same links, draws, loss, latency and counters, as arrays. Each
message is encoded and decoded once (not once per copy), so what a receiver gets is still exactly
what the wire carries.
"""

from __future__ import annotations

import numpy as np

from protocols.message_base import Message
from protocols.transport import Delivery

__all__ = ["BatchedRadio"]


class BatchedRadio:
    """Sends and polls one network's copies in batches; the network keeps the books.

    A message is kept until its copies have arrived or :attr:`HORIZON` seconds have passed (far beyond
    any latency the swarm's links are given).

    Parameters
    ----------
    network : protocols.network.SimulatedNetwork
    names : sequence of str
        The agents, in the network's order (``network.config.agents``).
    """

    HORIZON = 60.0

    def __init__(self, network, names):
        self.network = network
        self.names = tuple(names)
        if tuple(network.config.agents) != self.names:
            raise ValueError("the radio's names must be the network's agents, in its order")
        self._index = {n: i for i, n in enumerate(self.names)}
        self._payloads: dict[int, list[Message]] = {}  # batch id -> message of each copy row
        self._rows: dict[int, np.ndarray] = {}  # batch id -> message index of each copy row
        self._sent_at: dict[int, float] = {}  # batch id -> send time [s]

    def send(self, messages, now: float, sent: np.ndarray) -> tuple[int, int]:
        """Put ``messages`` on the radio at ``now`` (one batch per kind, in their order).

        Parameters
        ----------
        messages : sequence of Message
            Broadcasts go to every other agent, the rest to their receiver.
        now : float
            Send time [s].
        sent : ndarray, shape (n, n)
            Copies sent per (sender, receiver), incremented in place.

        Returns
        -------
        (int, int)
            Copies and bytes put on the radio.
        """
        n = len(self.names)
        by_kind: dict[str, list[Message]] = {}
        for msg in messages:
            by_kind.setdefault(msg.KIND, []).append(msg)
        copies = size_total = 0
        for kind, msgs in by_kind.items():
            senders, receivers, sizes, rows, wire = [], [], [], [], []
            for m, msg in enumerate(msgs):
                frame = msg.to_bytes()
                wire.append(Message.from_bytes(frame))  # what every receiver decodes
                a = self._index[msg.sender]
                to = [b for b in range(n) if b != a] if msg.is_broadcast else [self._index[msg.receiver]]
                senders += [a] * len(to)
                receivers += to
                sizes += [len(frame)] * len(to)
                rows += [m] * len(to)
            s, r = np.asarray(senders, np.int64), np.asarray(receivers, np.int64)
            np.add.at(sent, (s, r), 1)
            batch = self.network.send_many(kind, s, r, np.asarray(sizes, np.int64), now)
            self._payloads[batch], self._rows[batch], self._sent_at[batch] = wire, np.asarray(rows, np.int64), now
            copies += len(senders)
            size_total += int(sum(sizes))
        return copies, size_total

    def poll(self, now: float) -> dict[str, list[Delivery]]:
        """Every copy that has arrived by ``now``, per receiver, in arrival order."""
        got = self.network.poll_many(now)
        out: dict[str, list[Delivery]] = {n: [] for n in self.names}
        for b, i, r, t0, t1, size, dup in zip(got.batch.tolist(), got.index.tolist(), got.receiver.tolist(),
                                               got.sent_at.tolist(), got.arrival.tolist(), got.size.tolist(),
                                               got.duplicate.tolist()):
            msg = self._payloads[b][self._rows[b][i]]
            out[self.names[r]].append(Delivery(msg, self.names[r], t0, t1, size, dup))
        self._forget(now)
        return out

    def _forget(self, now: float) -> None:
        """Drop the payloads of batches none of whose copies can still arrive: all of them when nothing is
        in flight, else those sent more than :attr:`HORIZON` seconds before ``now``."""
        if sum(self.network.pending(a) for a in self.names) == 0:
            old = list(self._payloads)
        else:
            old = [b for b, t in self._sent_at.items() if t < now - self.HORIZON]
        for b in old:
            del self._payloads[b], self._rows[b], self._sent_at[b]
