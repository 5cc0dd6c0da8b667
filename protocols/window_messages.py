"""The messages of one agent's window sharing, built from a window's state (and the forms of those that arrive).

:class:`protocols.window_aggregation.WindowAggregation` decides *when* to send what; this module holds
*what* goes out: a window's records as an ``admm.bundle`` or as an ``admm.delta`` (only the forms the
parent lacks, :mod:`protocols.form_cache`), this agent's own forms by broadcast as ``admm.factors_delta``
(what changed, and a digest) or ``admm.factors`` (every form), and the reference's joint solution as
``admm.solution``; and it unpacks the forms of what arrives into :class:`decentral.admm.LocalProblem`
values keyed by ``(assembly, step)``.
"""

from __future__ import annotations

from typing import Iterable

import numpy as np

from decentral.admm import LocalProblem
from protocols.admm_messages import FactorShare, FormBundle
from protocols.delta_messages import DeltaBundle, FactorDelta, JointPoses
from protocols.form_cache import DeltaSender
from protocols.messages import BROADCAST
from protocols.window_share import OwnForms, WindowShare

__all__ = ["WindowMessages"]


class WindowMessages:
    """Builds the window-sharing messages of agent ``name``.

    Parameters
    ----------
    name : str
        The agent's assembly (the sender of every message built here).
    assemblies : sequence of str
        Every assembly's name (agent indices are positions in it).
    reference : str
        The assembly pinning the gauge.
    """

    def __init__(self, name: str, assemblies, reference: str):
        self.name, self.names, self.reference = name, tuple(assemblies), reference
        self.index = {a: i for i, a in enumerate(self.names)}
        self._delta_sender = DeltaSender()  # per parent, the forms already sent up to it
        self._edges_sent: set = set()  # the view graph in the last solution sent down (the reference)

    def slide(self, first: int) -> None:
        """Forms of steps before ``first`` left the window: no parent needs them any more."""
        self._delta_sender.slide(first)

    def problems(self, forms: Iterable) -> list:
        """Unpacked forms ``(keys, M, b_z, c_z, count)`` (keys as agent index and step) as ``[(keys, LocalProblem)]``."""
        return [(keys, LocalProblem(tuple((self.names[a], s) for a, s in keys), M, b_z, c_z, count))
                for keys, M, b_z, c_z, count in forms]

    def bundle(self, share: WindowShare, receiver: str, indices, *, down: bool, round_index: int,
               start: int = 0) -> FormBundle:
        """Records ``indices`` of ``share`` as an ``admm.bundle`` to ``receiver`` (``down``: the final set)."""
        return share.bundle(self.name, receiver, indices, down=down, start=start, round_index=round_index,
                            reference=self.index[self.reference])

    def delta(self, share: WindowShare, parent: int, indices: list[int], *, round_index: int,
              every: bool = False) -> DeltaBundle | None:
        """Records ``indices`` of ``share`` for ``parent`` as a delta (:class:`protocols.form_cache.DeltaSender`):
        the forms not yet sent to it (``every``: all of them) and each record's digest; ``None``: they go whole."""
        agg = share.agg
        packed = self._delta_sender.delta(parent, {i: agg.records[i] for i in indices}, share.step, every=every)
        if packed is None:
            return None
        carried, digests = packed
        pin = share.pin if share.pin is not None and self.index[self.reference] in indices else np.zeros(0)
        return DeltaBundle(sender=self.name, receiver=self.names[parent], round=round_index, step=share.step,
                           hop=agg.hop, parent=parent, depth=agg.depth,
                           members=np.array(sorted(indices), dtype=np.int16), pin=pin,
                           digest=np.array(digests, dtype=np.int64).reshape(-1, 2),
                           **DeltaBundle.pack(share.step, carried))

    def solution(self, share: WindowShare, joint, placeable: set[int], round_index: int) -> JointPoses:
        """The reference's joint solution of ``share`` as it goes down (``placeable``: agent indices placed at the
        window's step), with the view graph when it changed since the last solution built here."""
        edges = share.edges()
        previous, self._edges_sent = self._edges_sent, edges
        return share.solution_message(self.name, joint, self.index, placeable, edges if edges != previous else None,
                                      round_index, len(self.names))

    def factors(self, own: OwnForms, share: WindowShare | None, receiver: str, round_index: int) -> FactorShare:
        """This agent's own forms as ``admm.factors`` to ``receiver``, with the agents whose records it holds."""
        return FactorShare(sender=self.name, receiver=receiver, round=round_index, step=own.step,
                           have=np.array(self._have(own, share), dtype=np.int64), keys=own.keys, forms=own.forms,
                           pin=own.pin)

    def factors_delta(self, own: OwnForms, share: WindowShare | None, receiver: str, round_index: int,
                      every: bool = False) -> FactorDelta | FactorShare:
        """This agent's own forms as ``admm.factors_delta`` to ``receiver``: to everyone (``BROADCAST``), the forms
        not broadcast before and those of the window's last two steps (``every``: all of them); to one agent (an
        answer), all of them. ``admm.factors`` when a form is not over two poses within 255 steps."""
        everyone = receiver == BROADCAST
        key = -1 if everyone else self.index[receiver]  # (what went to everyone is kept apart from the answers)
        packed = self._delta_sender.delta(key, {self.index[self.name]: list(own.record)}, own.step,
                                          every=every or not everyone, again_from=own.step - 1)
        if packed is None:
            return self.factors(own, share, receiver, round_index)
        carried, digests = packed
        forms = carried.get(self.index[self.name], [])
        return FactorDelta(sender=self.name, receiver=receiver, round=round_index, step=own.step,
                           have=np.array(self._have(own, share), dtype=np.int16), pin=own.pin,
                           digest=np.array(digests[0], dtype=np.int64), **FactorDelta.pack(own.step, forms))

    def _have(self, own: OwnForms, share: WindowShare | None) -> list[int]:
        """Agents whose records of the own window this agent holds (itself at least)."""
        if share is not None and share.step == own.step:
            return sorted(share.records)
        return [self.index[self.name]]
