"""A BoT-SORT-style tracker of node circles that carries node ids through tag drop-outs (Liu et al. 2024 §III-C).

Per frame: every track's Kalman state is predicted one frame ahead and moved by the camera motion
(if given); detections are split by score; high-score detections are associated first with all
active and lost tracks, then the low-score ones with the tracks still unmatched (BoT-SORT's
two-stage association [1]_), on the cost 1 - IoU of circles whose radii are enlarged by a buffer
(small, fast circles then still overlap their prediction). Tag reads steer the association: a
detection whose tag names node X cannot join a track confidently carrying another node id, and
joins a (possibly lost) track carrying X even without overlap, within a distance gate.

Ids are votes: a track's node id is the node its tag reads named most often; a read that contradicts
the current id adds a vote but flips the id only once it strictly outnumbers it, and a track with at
least ``confident_votes`` reads for its id is never matched to a detection reading another tag. A
track carries its id through tag drop-outs while it is followed; once it has been lost (no
detection) for more than ``reverify_after`` frames and is found again, or is matched to a detection
that barely overlaps its prediction (with ``trust_uncontested``: only while another detection or
track competes for either), it shows its id only after a fresh read agrees, and while lost it waits where it was last seen. Two tracks never show the same node id in one frame: the one
with more votes for it keeps it.

References
----------
.. [1] N. Aharon, R. Orfaig, B.-Z. Bobrovsky, "BoT-SORT: Robust associations multi-pedestrian
   tracking", arXiv:2206.14651, 2022.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment

from agents.perception.kalman import CircleKalman, KalmanConfig, circle_iou, warp_state
from agents.perception.types import Circle, TagRead, TrackedCircle

__all__ = ["TrackerConfig", "Track", "CircleTracker"]

_BLOCK = 1e6  # cost of a forbidden pairing


@dataclass(frozen=True)
class TrackerConfig:
    """Parameters of :class:`CircleTracker`.

    Attributes
    ----------
    high_score : float
        Detections scoring at least this take part in the first association stage.
    new_track_score : float
        Unmatched detections scoring at least this start a track.
    match_iou, low_iou, tentative_iou : float
        Smallest (buffered) IoU accepted in the first stage, in the second (low-score) stage, and
        between new (tentative) tracks and detections.
    buffer : float
        Radii are scaled by ``1 + buffer`` (plus 2 px) for the association IoU.
    reid_distance : float
        A detection whose tag names a track's node joins it if their centres are within this many
        radii, even without overlap (re-identification after occlusion).
    radius_ratio : float
        A detection and a track whose radii differ by more than this ratio are never associated.
    confirm_hits : int
        Hits that turn a tentative track into a confirmed one (a track starting in the first frame
        is confirmed at once).
    max_lost : int
        Frames a track survives without a detection.
    confident_votes : int
        Reads of its node id that make a track's id confident.
    reverify_after : int
        A track found again after more than this many frames without a detection shows its id
        only after a fresh tag read agrees.
    verify_iou : float
        The same holds for a track whose detection overlaps its predicted circle by less than this
        IoU (plain circles): it may have jumped to a neighbouring node of the same size.
    verify_radius_ratio : float
        Nor does a track keep showing its id when its detection's radius differs from the predicted one
        by more than this ratio (a node's image grows or shrinks a few per cent a frame; a jump of a
        third is another node, e.g. a nearer one sliding in front of a hidden one), contested or not.
    trust_uncontested : bool
        With a detector that finds nearly every node, a low-overlap match that nothing contests
        (no other detection within the track's association gate, no other track whose gate holds
        the detection; buffered IoU >= ``match_iou``) is the node itself moving faster than
        predicted (a jerk, or a small fast node before its velocity is known), not a jump to a
        neighbour, and keeps the id. Off by default: with a detector that misses neighbours (the
        default's held-out recall is 0.55) such jumps are to undetected neighbours.
        :class:`~agents.perception.pipeline.Perception` turns it on for a detector whose
        ``finds_neighbours`` is True.
    settle_votes, settle_iou, reread_every : int, float, int
        :meth:`CircleTracker.settled`: a detection needs no tag read in this frame when exactly one
        active, verified track with at least ``settle_votes`` reads for its id overlaps it by at
        least ``settle_iou`` (plain circles, after prediction and camera motion), nothing else
        competes for either, and that track's circle was read within the last ``reread_every - 1``
        frames (``reread_every`` = 1 reads every circle in every frame).
    kalman : KalmanConfig
        Noise model of the circle Kalman filter.
    """

    high_score: float = 0.45
    new_track_score: float = 0.45
    match_iou: float = 0.1
    low_iou: float = 0.3
    tentative_iou: float = 0.2
    buffer: float = 0.3
    reid_distance: float = 3.0
    radius_ratio: float = 0.7
    confirm_hits: int = 2
    max_lost: int = 30
    confident_votes: int = 3
    reverify_after: int = 3
    verify_iou: float = 0.4
    verify_radius_ratio: float = 0.8
    trust_uncontested: bool = False
    settle_votes: int = 4
    settle_iou: float = 0.6
    reread_every: int = 3
    kalman: KalmanConfig = field(default_factory=KalmanConfig)


@dataclass
class Track:
    """Mutable state of one track (internal to :class:`CircleTracker`, exposed for inspection)."""

    track_id: int
    mean: np.ndarray
    cov: np.ndarray
    votes: dict[int, int] = field(default_factory=dict)
    node: int | None = None
    hits: int = 1
    lost: int = 0
    confirmed: bool = False
    verified: bool = True
    read_frame: int = 0

    @property
    def circle(self) -> np.ndarray:
        """Current (u, v, r), shape (3,)."""
        return self.mean[:3]

    def vote(self, node: int) -> None:
        """Count one tag read naming ``node``; the id flips only when strictly outnumbered."""
        self.votes[node] = self.votes.get(node, 0) + 1
        if self.node is None or self.votes[node] > self.votes.get(self.node, 0):
            self.node = node


class CircleTracker:
    """BoT-SORT-style circle tracker; implements :class:`~agents.perception.types.Tracker`."""

    def __init__(self, config: TrackerConfig | None = None):
        self.config = config or TrackerConfig()
        self.kf = CircleKalman(self.config.kalman)
        self.tracks: list[Track] = []
        self.frame = 0
        self._next_id = 1
        self._unread: set[int] = set()
        self._predicted: tuple | None = None  # (frame, motion, [(mean, cov)]) from settled()

    def reset(self) -> None:
        """Forget every track (a new sequence starts)."""
        self.tracks = []
        self.frame = 0
        self._next_id = 1
        self._unread = set()
        self._predicted = None

    def settled(self, circles: Sequence[Circle], *, motion: np.ndarray | None = None) -> np.ndarray:
        """Which of the coming frame's circles need no tag read, shape (N,) bool.

        A circle is settled when its track is beyond doubt: exactly one active (not lost), confirmed,
        verified track with at least ``settle_votes`` reads for its node id overlaps it by IoU >=
        ``settle_iou`` (plain circles, the track predicted and moved by ``motion``), that track
        overlaps no other circle and the circle no other track (IoU >= ``match_iou``), and the track's
        circle was read within the last ``reread_every - 1`` frames. Reading it would at most add a
        vote to an id that a contradicting read cannot flip anyway (it is confident), so the read is
        skipped; every ``reread_every``-th frame it is read again. Nothing changes state here except
        the note, for the next :meth:`update`, of which circles went unread (their tracks keep the
        frame of their last read).
        """
        cfg = self.config
        n = len(circles)
        out = np.zeros(n, dtype=bool)
        self._unread = set()
        if n == 0 or not self.tracks or cfg.reread_every <= 1:
            return out
        eligible = []
        for t in self.tracks:
            sure = self._confident_node(t)
            eligible.append(sure is not None and t.confirmed and t.verified and t.lost == 0
                            and t.votes.get(sure, 0) >= cfg.settle_votes and self.frame + 1 - t.read_frame < cfg.reread_every)
        if not any(eligible):  # the usual case without confident ids: no prediction needed
            return out
        out = self._sole_owner(circles, eligible, motion)
        self._unread = set(np.flatnonzero(out).tolist())
        return out

    def carried(self, circles: Sequence[Circle], *, motion: np.ndarray | None = None) -> np.ndarray:
        """Which of the coming frame's circles carry an id no tag read can change, shape (N,) bool.

        As :meth:`settled`, with a confident id (``confident_votes`` reads) in place of
        ``settle_votes`` and without the re-reading schedule: exactly one active, confirmed,
        verified track whose id is confident overlaps the circle by IoU >= ``settle_iou``, and
        neither touches another. A read there can only add a vote to that id (a contradicting one is
        refused), so :class:`~agents.perception.pipeline.Perception` spends no second, slower reader
        on such a circle when the first reads nothing. Changes no track (the predictions are kept
        for :meth:`update`).
        """
        if len(circles) == 0 or not self.tracks:
            return np.zeros(len(circles), dtype=bool)
        eligible = [t.confirmed and t.verified and t.lost == 0 and self._confident_node(t) is not None
                    for t in self.tracks]
        return self._sole_owner(circles, eligible, motion) if any(eligible) else np.zeros(len(circles), dtype=bool)

    def _sole_owner(self, circles: Sequence[Circle], eligible: list[bool], motion: np.ndarray | None) -> np.ndarray:
        """Circles (N,) bool overlapped by IoU >= ``settle_iou`` by exactly one track, an eligible one,
        that touches no other circle (IoU >= ``match_iou``), radii within ``radius_ratio``; the
        tracks predicted to the coming frame and moved by ``motion`` (kept for :meth:`update`)."""
        cfg = self.config
        out = np.zeros(len(circles), dtype=bool)
        if self._predicted is None or self._predicted[0] != self.frame or self._predicted[1] is not motion \
                or len(self._predicted[2]) != len(self.tracks):
            self._predicted = (self.frame, motion, [self._predict(t, motion) for t in self.tracks])
        preds = [mean[:3] for mean, _ in self._predicted[2]]
        dets = np.array([[c.u, c.v, c.r] for c in circles], dtype=float)
        iou = circle_iou(np.array(preds), dets)  # (tracks, circles)
        touch = iou >= cfg.match_iou
        for i, t in enumerate(self.tracks):
            if not eligible[i] or touch[i].sum() != 1:
                continue
            j = int(np.argmax(iou[i]))
            ratio = min(preds[i][2], dets[j, 2]) / max(preds[i][2], dets[j, 2])
            if iou[i, j] >= cfg.settle_iou and touch[:, j].sum() == 1 and ratio >= cfg.radius_ratio:
                out[j] = True
        return out

    def _predict(self, t: Track, motion: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """Track ``t``'s state predicted one frame ahead and moved by ``motion``."""
        mean, cov = self.kf.predict(t.mean, t.cov)
        if motion is not None:
            mean, cov = warp_state(mean, cov, np.asarray(motion, dtype=float))
        return mean, cov

    # -- association helpers -------------------------------------------------------------------
    def _confident_node(self, t: Track) -> int | None:
        if t.node is not None and t.votes.get(t.node, 0) >= self.config.confident_votes:
            return t.node
        return None

    def _cost(self, tracks: list[Track], dets: np.ndarray, nodes: list[int | None], min_iou: float) -> np.ndarray:
        """Cost matrix (tracks x dets): 1 - buffered IoU, id rules applied, gated to _BLOCK."""
        cfg = self.config
        if not tracks or len(dets) == 0:
            return np.zeros((len(tracks), len(dets)))
        tc = np.array([t.circle for t in tracks])
        iou = self._buffered_iou(tc, dets)
        cost = np.where(iou >= min_iou, 1.0 - iou, _BLOCK)
        # a circle much smaller or larger than the track is another object (e.g. a sticker's square)
        ratio = np.minimum(tc[:, None, 2], dets[None, :, 2]) / np.maximum(tc[:, None, 2], dets[None, :, 2])
        cost[ratio < cfg.radius_ratio] = _BLOCK
        for i, t in enumerate(tracks):
            sure = self._confident_node(t)
            for j, node in enumerate(nodes):
                if node is None:
                    continue
                if sure is not None and node != sure:
                    cost[i, j] = _BLOCK  # refuse an id swap
                elif t.node == node:
                    d = np.hypot(*(tc[i, :2] - dets[j, :2]))
                    if d <= cfg.reid_distance * max(tc[i, 2], dets[j, 2]):
                        cost[i, j] = min(cost[i, j], 0.5 * (1.0 - iou[i, j]))  # a read agreeing with the id
        return cost

    @staticmethod
    def _assign(cost: np.ndarray) -> list[tuple[int, int]]:
        if cost.size == 0:
            return []
        rows, cols = linear_sum_assignment(cost)
        return [(int(r), int(c)) for r, c in zip(rows, cols) if cost[r, c] < _BLOCK]

    # -- one frame -----------------------------------------------------------------------------
    def update(
        self,
        circles: Sequence[Circle],
        reads: Sequence[TagRead | None],
        *,
        motion: np.ndarray | None = None,
    ) -> list[TrackedCircle]:
        """Advance one frame; return one :class:`TrackedCircle` per input circle, in order."""
        cfg = self.config
        if len(circles) != len(reads):
            raise ValueError("circles and reads must have the same length")
        first_frame = self.frame == 0
        self.frame += 1
        unread, self._unread = self._unread, set()
        # the predictions settled() made for this frame with this motion, if any (the same values)
        frame, moved, done = self._predicted if self._predicted is not None else (-1, None, None)
        reuse = frame == self.frame - 1 and moved is motion and done is not None and len(done) == len(self.tracks)
        self._predicted = None
        for i, t in enumerate(self.tracks):
            t.mean, t.cov = done[i] if reuse else self._predict(t, motion)
        dets = np.array([[c.u, c.v, c.r] for c in circles], dtype=float).reshape(-1, 3)
        scores = np.array([c.score for c in circles], dtype=float)
        # (tracks, dets): pairs within the association gate before matching (only trust_uncontested asks)
        gate = self._gate(dets) if cfg.trust_uncontested else None
        row = {id(t): i for i, t in enumerate(self.tracks)}
        nodes = [r.node if r is not None else None for r in reads]
        owner: dict[int, Track] = {}  # detection index -> track

        def run(tracks: list[Track], idx: list[int], min_iou: float) -> list[Track]:
            cost = self._cost(tracks, dets[idx], [nodes[j] for j in idx], min_iou)
            matched = set()
            for ti, dj in self._assign(cost):
                owner[idx[dj]] = tracks[ti]
                matched.add(ti)
            return [t for i, t in enumerate(tracks) if i not in matched]

        high = [j for j in range(len(dets)) if scores[j] >= cfg.high_score]
        low = [j for j in range(len(dets)) if scores[j] < cfg.high_score]
        pool = [t for t in self.tracks if t.confirmed]
        tentative = [t for t in self.tracks if not t.confirmed]
        # stage 1: high-score detections with confirmed tracks (active and lost)
        left = run(pool, high, cfg.match_iou)
        # stage 2: low-score detections with the active tracks left over
        run([t for t in left if t.lost == 0], [j for j in low if j not in owner], cfg.low_iou)
        # tentative tracks with the high-score detections left over
        run(tentative, [j for j in high if j not in owner], cfg.tentative_iou)

        updated = set()
        for j, t in owner.items():
            # overlap of the plain (not enlarged) circles: a track that only reached its detection
            # through the buffer may have jumped to a neighbouring node
            close = float(circle_iou(t.circle[None], dets[j][None])[0, 0]) >= cfg.verify_iou \
                or (cfg.trust_uncontested and not self._contested(gate, row[id(t)], j))
            r0, r1 = float(t.circle[2]), float(dets[j][2])
            close = close and min(r0, r1) >= cfg.verify_radius_ratio * max(r0, r1)
            t.mean, t.cov = self.kf.update(t.mean, t.cov, dets[j])
            t.hits += 1
            if t.lost > cfg.reverify_after or not close:
                t.verified = False  # re-found after a long gap or a jump: its id needs a fresh tag read
            t.lost = 0
            if t.hits >= cfg.confirm_hits:
                t.confirmed = True
            if j not in unread:
                t.read_frame = self.frame
            if nodes[j] is not None:
                t.vote(nodes[j])
                if nodes[j] == t.node:
                    t.verified = True
            updated.add(id(t))
        survivors = []
        for t in self.tracks:
            if id(t) in updated:
                survivors.append(t)
            elif t.confirmed and t.lost < cfg.max_lost:
                t.lost += 1
                t.mean = t.mean.copy()
                t.mean[3:] = 0.0  # a lost track waits where it was last seen rather than drifting
                survivors.append(t)
        self.tracks = survivors
        for j in range(len(dets)):
            if j in owner or scores[j] < cfg.new_track_score or self._inside_known(dets[j], owner, j):
                continue
            mean, cov = self.kf.initiate(dets[j])
            t = Track(self._next_id, mean, cov, confirmed=first_frame, read_frame=self.frame)
            self._next_id += 1
            if nodes[j] is not None:
                t.vote(nodes[j])
            self.tracks.append(t)
            owner[j] = t
        self._retire_duplicates(owner)
        return self._outputs(circles, reads, owner)

    def _buffered_iou(self, circles: np.ndarray, dets: np.ndarray) -> np.ndarray:
        """IoU (T, N) of circles (T, 3) and detections (N, 3) with radii scaled by ``1 + buffer`` plus 2 px."""
        grow = np.array([1.0, 1.0, 1.0 + self.config.buffer])
        return circle_iou(circles * grow + [0, 0, 2.0], dets * grow + [0, 0, 2.0])

    def _gate(self, dets: np.ndarray) -> np.ndarray:
        """Which (track, detection) pairs lie within the association gate (buffered IoU >= ``match_iou``), (T, N) bool."""
        if not self.tracks or len(dets) == 0:
            return np.zeros((len(self.tracks), len(dets)), dtype=bool)
        return self._buffered_iou(np.array([t.circle for t in self.tracks]), dets) >= self.config.match_iou

    @staticmethod
    def _contested(gate: np.ndarray, i: int, j: int) -> bool:
        """Whether track ``i``'s pairing with detection ``j`` had a rival: another detection in the
        track's gate or another track whose gate holds the detection."""
        return bool(np.delete(gate[i], j).any() or np.delete(gate[:, j], i).any())

    def _inside_known(self, det: np.ndarray, owner: dict[int, Track], j: int) -> bool:
        """Whether an unmatched detection sits inside a node already known (it must not start a track).

        A circle whose centre lies within a confirmed track's circle (or within a circle matched in
        this frame) while being clearly smaller is the outline of a sticker or another edge inside
        that node: nodes share one physical size, and a farther node's centre cannot show through a
        nearer one. Such one-frame detections used to start short-lived tracks (most of the
        track-number switches on rendered table1 frames).
        """
        cfg = self.config
        known = [t.circle for t in self.tracks if t.confirmed and id(t) not in {id(o) for o in owner.values()}]
        known += [t.circle for i, t in owner.items() if i != j]
        for c in known:
            if np.hypot(det[0] - c[0], det[1] - c[1]) < c[2] and det[2] < cfg.radius_ratio * c[2]:
                return True
        return False

    def _retire_duplicates(self, owner: dict[int, Track]) -> None:
        """Drop lost tracks whose confident node id now belongs to a track seen in this frame."""
        seen = {self._confident_node(t) for t in owner.values()} - {None}
        self.tracks = [t for t in self.tracks if not (t.lost > 0 and self._confident_node(t) in seen)]

    def _outputs(self, circles, reads, owner: dict[int, Track]) -> list[TrackedCircle]:
        # a node id shows on at most one detection: the track with the most votes for it keeps it
        claim: dict[int, tuple[int, int]] = {}  # node -> (votes, detection index)
        for j, t in owner.items():
            if t.node is not None and t.verified:
                v = t.votes.get(t.node, 0)
                if t.node not in claim or v > claim[t.node][0]:
                    claim[t.node] = (v, j)
        out = []
        for j, (c, r) in enumerate(zip(circles, reads)):
            t = owner.get(j)
            node = None
            if t is not None and t.node is not None and t.verified and claim[t.node][1] == j:
                node = t.node
            elif t is None and r is not None and r.node is not None and r.node not in claim:
                node = r.node
                claim[node] = (0, j)
            # as in BoT-SORT, a track's number is shown once it is confirmed (a one-frame detection never shows one)
            out.append(TrackedCircle(c, r, node, t.track_id if t is not None and t.confirmed else None))
        return out
