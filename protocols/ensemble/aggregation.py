"""Aggregation towards a group leader and dissemination from it, over the group's spanning tree.

A convergecast (:class:`Convergecast`) is the receive half at every tree node: it collects one
:class:`~protocols.ensemble.messages.Report` per child, and once all are in, :func:`combine` merges
them with the node's own contribution into the report for its parent (or, at the leader, the
aggregate of the whole group). :func:`combine` is the pure reduction per step; the payloads are
dicts of arrays whose size depends on what is aggregated, not on how many modules contributed
(keyed sums), except for the leaf step, which gathers a small group's observations.

Steps and their payloads:

- ``count``: ``size`` (1,) modules in the subtree.
- ``abstract``: abstract-graph edges ``ea``, ``eb`` (cluster leader ids), ``ew`` (observation
  count), and clusters ``cid``, ``csize``, ``cmin`` (module count, smallest module id).
- ``leaf``: ``ids`` (modules), observations ``oi``, ``oj``, ``oz`` (E, d) inside the group.
- ``align``: ordered part pairs ``pa``, ``pb`` (part leader ids), their alignment statistics
  ``stats`` (m, 3 + 2d + d^2) (:meth:`decentral.ensemble.AlignmentStats.to_array`, linear in the
  points, so partial sums add) and ``links`` (directed observations from ``pa`` to ``pb``).
- ``grad``: ``g`` (1,) largest gradient entry in the subtree.
"""

from __future__ import annotations

import numpy as np

from decentral.errors import ProtocolError

__all__ = ["combine", "Convergecast", "split_by_subtree"]


def _keyed_sum(keys: list[np.ndarray], sums: dict[str, np.ndarray], mins: dict[str, np.ndarray]) -> tuple:
    stacked = np.stack(keys, 1) if keys else np.zeros((0, 0), dtype=np.int64)
    if stacked.shape[0] == 0:
        return keys, sums, mins
    uniq, inverse = np.unique(stacked, axis=0, return_inverse=True)
    inverse = inverse.ravel()
    m = uniq.shape[0]
    out_sums = {}
    for name, v in sums.items():
        acc = np.zeros((m,) + v.shape[1:], dtype=np.float64 if v.dtype.kind == "f" else np.int64)
        np.add.at(acc, inverse, v)
        out_sums[name] = acc
    out_mins = {}
    for name, v in mins.items():
        acc = np.full(m, np.iinfo(np.int64).max, dtype=np.int64)
        np.minimum.at(acc, inverse, v)
        out_mins[name] = acc
    return [uniq[:, k].astype(np.int64) for k in range(uniq.shape[1])], out_sums, out_mins


def combine(step: str, payloads: list[dict]) -> dict:
    """Merge the payloads of one convergecast ``step`` (a pure function; order does not matter
    except for the floating-point order of sums)."""
    if not payloads:
        raise ProtocolError(f"nothing to combine for step {step!r}")
    cat = {k: np.concatenate([np.asarray(p[k]) for p in payloads]) for k in payloads[0]}
    if step == "count":
        return {"size": np.array([int(cat["size"].sum())], dtype=np.int64)}
    if step == "grad":
        return {"g": np.array([float(cat["g"].max())])}
    if step == "leaf":
        return cat
    if step == "abstract":
        (ea, eb), s, _ = _keyed_sum([cat["ea"], cat["eb"]], {"ew": cat["ew"]}, {})
        (cid,), cs, cm = _keyed_sum([cat["cid"]], {"csize": cat["csize"]}, {"cmin": cat["cmin"]})
        return {"ea": ea, "eb": eb, "ew": s["ew"], "cid": cid, "csize": cs["csize"], "cmin": cm["cmin"]}
    if step == "align":
        (pa, pb), s, _ = _keyed_sum([cat["pa"], cat["pb"]], {"stats": cat["stats"], "links": cat["links"]}, {})
        return {"pa": pa, "pb": pb, "stats": s["stats"], "links": s["links"]}
    raise ProtocolError(f"unknown convergecast step {step!r}")


class Convergecast:
    """Receive half of one convergecast at one tree node: waits for a report from every child.

    Parameters
    ----------
    step : str
        The step being aggregated.
    children : iterable of int
        The node's children in the group tree.
    """

    __slots__ = ("step", "children", "received")

    def __init__(self, step: str, children):
        self.step = step
        self.children = frozenset(int(c) for c in children)
        self.received: dict[int, dict] = {}

    def receive(self, child: int, payload: dict) -> None:
        """Store ``child``'s report (a duplicate replaces the earlier copy; strangers are refused)."""
        if child not in self.children:
            raise ProtocolError(f"report from {child}, which is not a child")
        self.received[child] = {k: np.asarray(v) for k, v in payload.items()}

    @property
    def complete(self) -> bool:
        """Whether every child has reported."""
        return len(self.received) == len(self.children)

    def result(self, own: dict) -> dict:
        """The subtree's aggregate: own contribution combined with the children's, in child order."""
        return combine(self.step, [own] + [self.received[c] for c in sorted(self.received)])


def split_by_subtree(ids: np.ndarray, values: dict[str, np.ndarray], members: dict[int, np.ndarray]) -> dict[int, dict]:
    """Rows of ``values`` (indexed like ``ids``) for each child's subtree ``members[child]``."""
    out = {}
    for child, sub in members.items():
        rows = np.flatnonzero(np.isin(ids, sub))
        out[child] = {"ids": ids[rows], **{k: v[rows] for k, v in values.items()}}
    return out
