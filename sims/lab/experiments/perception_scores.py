"""Scoring perception output against the truth of :mod:`sims.lab.experiments.varied_scenes` frames (and of
any frame whose ``spheres`` have ``id, u, v, r`` and whose ``visible`` gives their visible fractions, such as
:class:`sims.lab.experiments.mottled_scenes.MottledFrame`).

Definitions (one frame at a time, then summed over a sequence):

- A sphere **counts** when at least ``min_visible`` (default half) of its disc shows in the frame.
- A detection **matches** a sphere when its centre is within ``max(2 px, 0.1 r)`` of the sphere's
  and its radius within 10 % of ``r``; each sphere takes at most one detection, nearest first.
  **Recall** = matched counted spheres / counted spheres.
- A detection is **on** a sphere when its centre lies within half the sphere's radius of its centre
  (one detection per sphere, nearest first). Detections on no sphere are **false circles**; the
  second and later detections on one sphere are **double circles**. Both are reported as a share
  of the counted spheres.
- **Wrong ids**: detections showing a node id that is not the id of the sphere they are on (or on
  no sphere), as a share of the detections showing an id.
- **Carried ids**: detections on a sphere without a tag read in that frame, after the sphere's tag
  had been read at least once in the sequence: the share of them that show the sphere's id.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from agents.perception.types import TrackedCircle
from sims.lab.experiments.varied_scenes import Frame

__all__ = ["SequenceScore", "score_frame"]


@dataclass
class SequenceScore:
    """Counts accumulated over the frames of a sequence (see the module docstring)."""

    counted: int = 0
    matched: int = 0
    detections: int = 0
    false_circles: int = 0
    double_circles: int = 0
    shown_ids: int = 0
    wrong_ids: int = 0
    unread: int = 0
    carried: int = 0
    tags_visible: int = 0
    tags_read: int = 0
    radius_err: list = field(default_factory=list)
    centre_err: list = field(default_factory=list)
    seen_read: set = field(default_factory=set)

    def summary(self) -> dict:
        """Rates and medians of the accumulated counts (None where undefined)."""
        def ratio(a, b):
            return a / b if b else None
        return {
            "counted_spheres": self.counted,
            "recall": ratio(self.matched, self.counted),
            "false_circles_per_sphere": ratio(self.false_circles, self.counted),
            "double_circles_per_sphere": ratio(self.double_circles, self.counted),
            "wrong_id_share": ratio(self.wrong_ids, self.shown_ids),
            "carried_id_share": ratio(self.carried, self.unread),
            "unread_detections": self.unread,
            "tag_read_share": ratio(self.tags_read, self.tags_visible),
            "radius_rel_err_median": float(np.median(self.radius_err)) if self.radius_err else None,
            "radius_rel_err_p90": float(np.percentile(self.radius_err, 90)) if self.radius_err else None,
            "centre_err_px_median": float(np.median(self.centre_err)) if self.centre_err else None,
        }


def _assign(cost: np.ndarray, ok: np.ndarray) -> list[tuple[int, int]]:
    """Greedy one-to-one pairs (row, column) of allowed entries, cheapest first."""
    pairs, used_r, used_c = [], set(), set()
    rows, cols = np.nonzero(ok)
    for k in np.argsort(cost[rows, cols], kind="stable"):
        i, j = int(rows[k]), int(cols[k])
        if i not in used_r and j not in used_c:
            used_r.add(i)
            used_c.add(j)
            pairs.append((i, j))
    return pairs


def score_frame(score: SequenceScore, frame: Frame, dets: list[TrackedCircle], *, min_visible: float = 0.5,
                tag_visible: np.ndarray | None = None) -> None:
    """Add one frame's detections ``dets`` to ``score``.

    ``tag_visible`` (bool per sphere, optional) marks spheres whose tag faces the camera; it only
    feeds the tag read share.
    """
    sp = frame.spheres
    truth = np.array([[s.u, s.v, s.r] for s in sp], dtype=float).reshape(-1, 3)
    est = np.array([[d.circle.u, d.circle.v, d.circle.r] for d in dets], dtype=float).reshape(-1, 3)
    dist = np.hypot(est[:, None, 0] - truth[None, :, 0], est[:, None, 1] - truth[None, :, 1])
    rel = np.abs(est[:, None, 2] - truth[None, :, 2]) / truth[None, :, 2]
    counted = frame.visible >= min_visible
    score.counted += int(counted.sum())
    score.detections += len(dets)
    tight = (dist <= np.maximum(2.0, 0.1 * truth[None, :, 2])) & (rel <= 0.1) & counted[None, :]
    for i, j in _assign(dist + truth[None, :, 2] * rel, tight):
        score.matched += 1
        score.radius_err.append(float(rel[i, j]))
        score.centre_err.append(float(dist[i, j]))
    on = _assign(dist / truth[None, :, 2], (dist <= 0.5 * truth[None, :, 2]) & (frame.visible[None, :] > 0))
    sphere_of = dict(on)
    inside_any = (dist <= truth[None, :, 2]).any(axis=1) if len(sp) else np.zeros(len(dets), bool)
    for i, d in enumerate(dets):
        j = sphere_of.get(i)
        if j is None:
            if inside_any[i]:
                score.double_circles += 1
            else:
                score.false_circles += 1
        if d.node is not None:
            score.shown_ids += 1
            score.wrong_ids += j is None or d.node != sp[j].id
        if j is None:
            continue
        node = sp[j].id
        if d.read is not None:
            score.seen_read.add(node)
        elif node in score.seen_read:
            score.unread += 1
            score.carried += d.node == node
    if tag_visible is not None:
        read = {sp[j].id for i, j in on if dets[i].read is not None and dets[i].read.node == sp[j].id}
        for j, s in enumerate(sp):
            if tag_visible[j] and counted[j]:
                score.tags_visible += 1
                score.tags_read += s.id in read
