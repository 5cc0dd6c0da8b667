"""Cutting a signed frame into datagrams and putting it back together (:mod:`protocols.udp_transport`).

A frame of ``count`` pieces travels as ``count`` data datagrams and, when it needs more than one,
``groups`` parity datagrams: data piece ``i`` belongs to group ``i mod groups`` (interleaved, so that a
burst of consecutive losses hits different groups), and a group's parity datagram carries the XOR of
its pieces, each padded with zeros to the full piece size. A receiver that misses one piece of a
group rebuilds it from the others and the parity. Over a link that loses each datagram with
probability ``p`` a frame of ``n`` pieces arrives whole with probability ``(1 - p)^n`` without parity;
with a parity per ``g`` pieces every group may lose one: at ``p = 0.1`` an 18 KB frame (16 pieces)
arrives 19 % of the time without parity and 71 % with ``g = 4`` (a quarter more bytes).

Each datagram is a 17-byte header, ``b"DG"`` | version 2 (u8) | frame id (u32) | index (u16) |
count (u16) | groups (u16) | frame length (u32), big-endian, then its piece of the frame (indices
``count .. count + groups - 1`` are the parity datagrams). Nothing here is trusted: the whole frame's
signature is checked after reassembly (:class:`protocols.auth.Gate`); the reassembler only bounds
what a sender can make a receiver hold (pieces per frame, frames in progress per source, bytes).
"""

from __future__ import annotations

import math
import struct

import numpy as np

from protocols.auth import Rejected

__all__ = ["HEADER", "PARITY_GROUP", "frame_arrival", "parity_groups", "split_frame", "Reassembler"]

HEADER = struct.Struct(">2sBIHHHI")
_MAGIC, _VERSION = b"DG", 2

#: data pieces per parity datagram by default: one lost datagram in every five sent costs nothing
PARITY_GROUP = 4
#: completed frames remembered (to ignore their late datagrams) at most
_MAX_DONE = 4096


def parity_groups(count: int, group: int) -> int:
    """Parity datagrams of a frame of ``count`` pieces with one parity per ``group`` pieces (0: none)."""
    return 0 if count < 2 or group < 1 else math.ceil(count / group)


def frame_arrival(size: int, loss: float, mtu: int, parity_group: int = PARITY_GROUP) -> float:
    """Probability that a frame of ``size`` bytes is put back together when each datagram is lost with
    probability ``loss`` (independently): every parity group must lose at most one of its datagrams.

    Examples
    --------
    >>> round(frame_arrival(18_000, 0.1, 1200, 0), 3), round(frame_arrival(18_000, 0.1, 1200), 3)
    (0.185, 0.712)
    >>> frame_arrival(500, 0.1, 1200)  # one datagram
    0.9
    """
    room = int(mtu) - HEADER.size
    count = max(1, math.ceil(int(size) / room))
    groups = parity_groups(count, int(parity_group))
    keep = 1.0 - float(loss)
    if not groups:
        return keep ** count
    p = 1.0
    for g in range(groups):
        n = len(range(g, count, groups)) + 1  # its data pieces and its parity
        p *= keep ** n + n * float(loss) * keep ** (n - 1)
    return p


def _xor(pieces: list[bytes], room: int) -> bytes:
    """XOR of ``pieces``, each padded with zeros to ``room`` bytes."""
    acc = np.zeros(room, np.uint8)
    for p in pieces:
        acc[:len(p)] ^= np.frombuffer(p, np.uint8)
    return acc.tobytes()


def split_frame(frame: bytes, mtu: int, frame_id: int, parity_group: int = PARITY_GROUP) -> list[bytes]:
    """The datagrams of ``frame``, each at most ``mtu`` bytes, header included: data, then parity.

    ``parity_group``: data pieces per parity datagram (0: no parity).

    Examples
    --------
    >>> parts = split_frame(b"x" * 2500, 1200, 7)
    >>> len(parts), max(len(p) for p in parts) <= 1200  # 3 data pieces, 1 parity
    (4, True)
    >>> len(split_frame(b"x" * 2500, 1200, 7, parity_group=0)), len(split_frame(b"x" * 100, 1200, 7))
    (3, 1)
    """
    room = int(mtu) - HEADER.size
    if room < 1:
        raise ValueError(f"mtu {mtu} leaves no room after the {HEADER.size}-byte header")
    count = max(1, math.ceil(len(frame) / room))
    groups = parity_groups(count, int(parity_group))
    if count + groups > 0xFFFF or len(frame) > 0xFFFFFFFF:
        raise ValueError("frame needs more than 65535 datagrams")
    fid = int(frame_id) & 0xFFFFFFFF
    chunks = [frame[i * room:(i + 1) * room] for i in range(count)]
    parity = [_xor(chunks[g::groups], room) for g in range(groups)]
    return [HEADER.pack(_MAGIC, _VERSION, fid, i, count, groups, len(frame)) + piece
            for i, piece in enumerate(chunks + parity)]


class _Frame:
    """One frame in progress: its pieces by index (data and parity) and what its header promised."""

    __slots__ = ("first_seen", "count", "groups", "length", "pieces", "bytes")

    def __init__(self, now: float, count: int, groups: int, length: int):
        self.first_seen, self.count, self.groups, self.length = now, count, groups, length
        self.pieces: dict[int, bytes] = {}
        self.bytes = 0

    def group_of(self, index: int) -> int:
        return index - self.count if index >= self.count else index % self.groups

    def recover(self, group: int) -> None:
        """Rebuild the one missing data piece of ``group`` from the others and its parity, if possible."""
        members = range(group, self.count, self.groups)
        missing = [i for i in members if i not in self.pieces]
        parity = self.pieces.get(self.count + group)
        if len(missing) != 1 or parity is None:
            return
        room = len(parity)  # a parity piece is as long as a full data piece
        i = missing[0]
        size = room if i < self.count - 1 else self.length - (self.count - 1) * room
        others = [self.pieces[j] for j in members if j != i]
        if not 0 < size <= room or any(len(q) > room for q in others):
            raise Rejected("malformed", "frame length does not match its pieces")
        rebuilt = _xor([parity] + others, room)
        self.pieces[i] = rebuilt[:size]

    def whole(self) -> bytes | None:
        if any(i not in self.pieces for i in range(self.count)):
            return None
        frame = b"".join(self.pieces[i] for i in range(self.count))
        if len(frame) != self.length:
            raise Rejected("malformed", "frame length does not match its pieces")
        return frame


class Reassembler:
    """Whole frames out of datagrams from many sources, with bounded memory.

    Parameters
    ----------
    max_frame_bytes : int
        A frame announcing more than this (or more pieces than this allows) is refused (``oversize``).
    timeout : float
        Seconds a frame in progress waits for its missing pieces (then it is dropped by :meth:`expire`).
    per_source : int
        Frames in progress per source address; the oldest is dropped beyond it.
    """

    def __init__(self, max_frame_bytes: int, timeout: float = 2.0, per_source: int = 64):
        self.max_frame_bytes, self.timeout, self.per_source = int(max_frame_bytes), float(timeout), int(per_source)
        self._open: dict[tuple, _Frame] = {}
        # frames with parity already returned: their datagrams still to come are ignored, not begun again
        self._done: dict[tuple, float] = {}
        self._dropped = 0

    def add(self, source, datagram: bytes, now: float) -> bytes | None:
        """Take one datagram; return the frame it completes, if any.

        Raises
        ------
        Rejected
            ``malformed`` (bad header, or pieces that disagree with it) or ``oversize``.
        """
        if len(datagram) < HEADER.size:
            raise Rejected("malformed", "datagram shorter than its header")
        magic, version, fid, index, count, groups, length = HEADER.unpack_from(datagram)
        if (magic != _MAGIC or version != _VERSION or count == 0 or index >= count + groups
                or groups > count or (count == 1 and groups)):
            raise Rejected("malformed", "bad datagram header")
        piece = datagram[HEADER.size:]
        if count == 1:
            if len(piece) != length:
                raise Rejected("malformed", "frame length does not match its piece")
            return bytes(piece)
        if length > self.max_frame_bytes or (count + groups) * max(len(piece), 1) > 2 * self.max_frame_bytes:
            raise Rejected("oversize", f"{count} pieces, {length} bytes")
        key = (source, fid)
        if key in self._done:  # a parity datagram (or a late piece) of a frame already rebuilt
            return None
        entry = self._open.get(key)
        if entry is None:
            mine = [k for k in self._open if k[0] == source]
            if len(mine) >= self.per_source:
                oldest = min(mine, key=lambda k: self._open[k].first_seen)
                del self._open[oldest]
                self._dropped += 1
            entry = self._open[key] = _Frame(now, count, groups, length)
        if (entry.count, entry.groups, entry.length) != (count, groups, length):
            del self._open[key]
            raise Rejected("malformed", "piece count or length changed within a frame")
        if index in entry.pieces:
            return None
        entry.pieces[index] = bytes(piece)
        entry.bytes += len(piece)
        if entry.bytes > 2 * self.max_frame_bytes:
            del self._open[key]
            raise Rejected("oversize", f"more than {self.max_frame_bytes} bytes")
        try:
            if groups:  # only the arriving piece's group can have become whole enough to rebuild
                entry.recover(entry.group_of(index))
            frame = entry.whole()
        except Rejected:
            del self._open[key]
            raise
        if frame is None:
            return None
        del self._open[key]
        if groups:
            self._done[key] = now
            if len(self._done) > _MAX_DONE:  # oldest first (insertion order)
                del self._done[next(iter(self._done))]
        return frame

    def expire(self, now: float) -> int:
        """Drop frames in progress for longer than ``timeout``; return how many were dropped since the last call."""
        old = [k for k, e in self._open.items() if now - e.first_seen > self.timeout]
        for k in old:
            del self._open[k]
        while self._done and now - next(iter(self._done.values())) > self.timeout:  # oldest first
            del self._done[next(iter(self._done))]
        n, self._dropped = self._dropped + len(old), 0
        return n
