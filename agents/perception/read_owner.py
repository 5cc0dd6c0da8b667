"""Which circle a tag read belongs to: a read is kept only where no other circle can own it.

An identifier reads the tag inside each circle's square region, and a tag near the rim of two
overlapping circles can be read in both regions: on frames where one sphere passes in front of
another, such reads named the wrong sphere. :func:`unambiguous_reads` keeps a read on circle ``i``
only when the geometry leaves no doubt that it is printed on ``i``'s node:

1. **Its four corners lie inside circle i** (within ``corner_slack`` radii, for the circle's and
   the corners' own errors): a print lies on its sphere, whose image is the disc.
2. **Its centre lies inside no other circle that could hide i**: nodes share one physical size,
   so the larger of two overlapping circles is the nearer sphere and hides the other where they
   overlap; a print whose centre lies in both discs is the nearer one's. A read is dropped from
   circle i when its centre lies inside a circle j whose radius is at least
   ``(1 - radius_margin)`` times i's (j is nearer, or too close in size to tell).
3. **No other circle keeps the same tag**: of two circles that still both hold a read of one tag,
   neither keeps it (the tracker then carries the ids).

Dropped reads become None (no read), never another circle's: the rule only removes reads.

Across frames, :class:`PrintScale` adds a fourth rule from the same fact (every node is the same
sphere with the same print): the print's longest side in the image is about one fixed fraction of its
node's image radius, whatever the distance (0.45-0.93 on the tuning scenes, whose prints vary in size
by a factor 1.7 between nodes; median 0.66). A read whose side is under half or over twice the recent
reads' median fraction does not belong to its circle: a circle drawn around two overlapping spheres
(the print is small for it) or around the print itself (the print is large for it).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence

import numpy as np

from agents.perception.types import Circle, TagRead

__all__ = ["PrintScale", "print_fraction", "unambiguous_reads"]


def unambiguous_reads(circles: Sequence[Circle], reads: Sequence[TagRead | None], *,
                      corner_slack: float = 0.2, radius_margin: float = 0.05) -> list[TagRead | None]:
    """The reads of ``circles`` with every read a nearer or overlapping circle could own set to None.

    Parameters
    ----------
    circles : sequence of Circle, length N
        All circles of the frame (image pixels), also those that were not read.
    reads : sequence of TagRead or None, length N
        ``reads[i]`` is the read found for ``circles[i]`` (corners (4, 2), image pixels).
    corner_slack : float
        Corners may lie up to ``(1 + corner_slack) r + 1`` px from the circle's centre.
    radius_margin : float
        A circle j containing the read's centre takes it away from circle i unless
        ``r_j < (1 - radius_margin) r_i`` (j then is farther, hidden by i where they overlap).

    Returns
    -------
    list of TagRead or None, length N
    """
    if len(circles) != len(reads):
        raise ValueError("circles and reads must have the same length")
    c = np.array([[x.u, x.v, x.r] for x in circles], dtype=float).reshape(-1, 3)
    out: list[TagRead | None] = list(reads)
    for i, read in enumerate(reads):
        if read is None:
            continue
        corners = np.asarray(read.corners, dtype=float).reshape(-1, 2)
        u, v, r = c[i]
        if np.any(np.hypot(corners[:, 0] - u, corners[:, 1] - v) > (1.0 + corner_slack) * r + 1.0):
            out[i] = None  # rule 1: part of the print lies outside the circle
            continue
        cu, cv = corners.mean(axis=0)
        inside = np.hypot(c[:, 0] - cu, c[:, 1] - cv) <= c[:, 2]
        inside[i] = False
        if np.any(inside & (c[:, 2] >= (1.0 - radius_margin) * r)):
            out[i] = None  # rule 2: a nearer (or equally near) circle covers the print
    tags: dict[int, list[int]] = {}
    for i, read in enumerate(out):
        if read is not None:
            tags.setdefault(read.tag, []).append(i)
    for held in tags.values():
        if len(held) > 1:  # rule 3
            for i in held:
                out[i] = None
    return out


def print_fraction(circle: Circle, read: TagRead) -> float:
    """The read print's longest side (image pixels) over ``circle``'s radius."""
    c = np.asarray(read.corners, dtype=float).reshape(-1, 2)
    side = float(np.max(np.hypot(*(c - np.roll(c, -1, axis=0)).T))) if len(c) else 0.0
    return side / circle.r if circle.r > 0 else float("inf")


class PrintScale:
    """Rule 4: a read whose print is far too small or too large for its circle is dropped.

    Keeps the print fractions (:func:`print_fraction`) of the last ``keep`` reads it let through;
    once it holds ``warm`` of them, a read whose fraction lies outside ``[m / factor, m * factor]``
    (``m`` their median) becomes None. One instance per camera sequence (:meth:`reset` between
    sequences): the fraction is the robots' own, learnt from their reads, not a constant.
    """

    def __init__(self, factor: float = 2.0, warm: int = 8, keep: int = 64):
        if factor <= 1.0 or warm < 1 or keep < warm:
            raise ValueError("factor > 1 and 1 <= warm <= keep")
        self.factor, self.warm = float(factor), int(warm)
        self._seen: deque[float] = deque(maxlen=int(keep))

    def reset(self) -> None:
        """Forget the fractions seen (a new sequence, perhaps another robot's camera)."""
        self._seen.clear()

    def median(self) -> float | None:
        """The median fraction of the reads let through (None until ``warm`` of them)."""
        return float(np.median(self._seen)) if len(self._seen) >= self.warm else None

    def filter(self, circles: Sequence[Circle], reads: Sequence[TagRead | None]) -> list[TagRead | None]:
        """``reads`` (one per circle, or None) with those of an implausible print size set to None."""
        m = self.median()
        out: list[TagRead | None] = []
        for circle, read in zip(circles, reads, strict=True):
            if read is not None:
                f = print_fraction(circle, read)
                if not (np.isfinite(f) and f > 0) or (m is not None and not m / self.factor <= f <= m * self.factor):
                    read = None
                else:
                    self._seen.append(f)
            out.append(read)
        return out
