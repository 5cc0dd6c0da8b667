"""Cutting a signed frame into datagrams and putting it back together (:mod:`protocols.udp_transport`).

Each datagram is a 11-byte header, ``b"DG"`` | version 1 (u8) | frame id (u32) | index (u16) |
count (u16), big-endian, then its piece of the frame. Nothing here is trusted: the whole frame's
signature is checked after reassembly (:class:`protocols.auth.Gate`); the reassembler only bounds
what a sender can make a receiver hold (pieces per frame, frames in progress per source, bytes).
"""

from __future__ import annotations

import math
import struct

from protocols.auth import Rejected

__all__ = ["HEADER", "split_frame", "Reassembler"]

HEADER = struct.Struct(">2sBIHH")
_MAGIC, _VERSION = b"DG", 1


def split_frame(frame: bytes, mtu: int, frame_id: int) -> list[bytes]:
    """The datagrams of ``frame``, each at most ``mtu`` bytes, header included.

    Examples
    --------
    >>> parts = split_frame(b"x" * 2500, 1200, 7)
    >>> len(parts), max(len(p) for p in parts) <= 1200
    (3, True)
    """
    room = int(mtu) - HEADER.size
    if room < 1:
        raise ValueError(f"mtu {mtu} leaves no room after the {HEADER.size}-byte header")
    count = max(1, math.ceil(len(frame) / room))
    if count > 0xFFFF:
        raise ValueError("frame needs more than 65535 datagrams")
    fid = int(frame_id) & 0xFFFFFFFF
    return [HEADER.pack(_MAGIC, _VERSION, fid, i, count) + frame[i * room:(i + 1) * room] for i in range(count)]


class Reassembler:
    """Whole frames out of datagrams from many sources, with bounded memory.

    Parameters
    ----------
    max_frame_bytes : int
        A frame announcing more pieces than this allows is refused (``oversize``).
    timeout : float
        Seconds a frame in progress waits for its missing pieces (then it is dropped by :meth:`expire`).
    per_source : int
        Frames in progress per source address; the oldest is dropped beyond it.
    """

    def __init__(self, max_frame_bytes: int, timeout: float = 2.0, per_source: int = 64):
        self.max_frame_bytes, self.timeout, self.per_source = int(max_frame_bytes), float(timeout), int(per_source)
        self._open: dict[tuple, list] = {}  # (source, id) -> [first seen, count, {index: piece}, bytes]
        self._dropped = 0

    def add(self, source, datagram: bytes, now: float) -> bytes | None:
        """Take one datagram; return the frame it completes, if any.

        Raises
        ------
        Rejected
            ``malformed`` (bad header) or ``oversize``.
        """
        if len(datagram) < HEADER.size:
            raise Rejected("malformed", "datagram shorter than its header")
        magic, version, fid, index, count = HEADER.unpack_from(datagram)
        if magic != _MAGIC or version != _VERSION or count == 0 or index >= count:
            raise Rejected("malformed", "bad datagram header")
        piece = datagram[HEADER.size:]
        if count == 1:
            return bytes(piece)
        if count * max(len(piece), 1) > 2 * self.max_frame_bytes:
            raise Rejected("oversize", f"{count} pieces")
        key = (source, fid)
        entry = self._open.get(key)
        if entry is None:
            mine = [k for k in self._open if k[0] == source]
            if len(mine) >= self.per_source:
                oldest = min(mine, key=lambda k: self._open[k][0])
                del self._open[oldest]
                self._dropped += 1
            entry = self._open[key] = [now, count, {}, 0]
        if entry[1] != count:
            raise Rejected("malformed", "piece count changed within a frame")
        if index not in entry[2]:
            entry[2][index] = bytes(piece)
            entry[3] += len(piece)
            if entry[3] > self.max_frame_bytes:
                del self._open[key]
                raise Rejected("oversize", f"more than {self.max_frame_bytes} bytes")
        if len(entry[2]) < count:
            return None
        del self._open[key]
        return b"".join(entry[2][i] for i in range(count))

    def expire(self, now: float) -> int:
        """Drop frames in progress for longer than ``timeout``; return how many were dropped since the last call."""
        old = [k for k, e in self._open.items() if now - e[0] > self.timeout]
        for k in old:
            del self._open[k]
        n, self._dropped = self._dropped + len(old), 0
        return n
