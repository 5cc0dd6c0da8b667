"""Authenticated frames: Ed25519 signing keys, the signed envelope, and the per-sender replay window.

Every frame a real transport puts on the wire is an *envelope* around one message frame
(:meth:`protocols.messages.Message.to_bytes`), signed by its sender with the sender's private
Ed25519 key (libsodium through PyNaCl: verifying took 41 µs of CPU against 84 µs with the
``cryptography`` package's OpenSSL, signing 16 against 26 µs, on this project's 2-core machine).
A receiver checks it against the public key that its peers file lists for the claimed sender, so a
member cannot forge another member's frames, and an outsider cannot forge any.

Envelope, version 1 (all integers little-endian; ``L`` = sender name length, ``N`` = inner length)::

    offset      size  field
    0           4     magic b"DCSE"
    4           1     envelope version (1)
    5           1     L, the sender name length in bytes (1..255)
    6           L     sender name, UTF-8
    6+L         8     epoch: u64, fixed for the life of the sending process (see below)
    14+L        8     seq: u64, 0, 1, 2, ... per sending process
    22+L        8     sent_at: f64, the sender's clock at sending (s)
    30+L        4     N: u32, length of the inner frame
    34+L        N     inner frame (the message wire format, CRC included)
    34+L+N      64    Ed25519 signature of bytes [0, 34+L+N)

So the envelope adds ``98 + L`` bytes to a frame. A receiver accepts a frame only if, in this order
(the first failing check names the reason it is refused with, see :data:`REJECT_REASONS`); the
cheap checks (1-4, :meth:`Gate.screen`) come before the signature (:meth:`Gate.verify`), so a frame
that can be refused without it costs a parse and a look-up:

1. it parses exactly: magic, a known version, a valid name, a finite ``sent_at`` and a total length
   of exactly ``98 + L + N`` -- else ``malformed`` (a truncated or padded frame is malformed);
2. the sender is in the peers file -- else ``unknown_sender``;
3. the pair (epoch, seq) is fresh for that sender (:class:`ReplayWindow`) -- else ``replay``;
4. when the gate has a clock tolerance (``max_age``), ``sent_at`` is no earlier than the
   receiver's own start (``since``) minus ``max_age``, and no later than the receiver's clock plus
   ``max_ahead`` -- else ``stale``;
5. the signature verifies with that sender's public key -- else ``bad_signature``;
6. the inner frame decodes -- else ``malformed``;
7. the inner message names the envelope's sender as its sender -- else ``bad_signature`` (a member
   speaking for another member is a forgery, even when signed with its own key);
8. the message is addressed to the receiving agent, or to everyone but is not the receiving agent's
   own broadcast -- else ``replay`` (a genuine frame that shows up at an agent it was not meant for
   can only be a copy of someone else's traffic, or of the agent's own, reflected back).

Step 3 only looks: the window remembers (epoch, seq) once the frame has passed every step, so a
refused frame never moves a sender's window (and a forged frame with a high sequence number, which
passes step 3, fails step 5 and moves nothing).

Restarts and replays. A sender's epoch is its process's start time in nanoseconds since the Unix
epoch (``time.time_ns()``), so a restarted sender, which starts its sequence at 0 again, comes back
with a larger epoch. A receiver keeps, per sender, the newest epoch it has seen and a sliding window
over that epoch's sequence numbers: a frame of a newer epoch resets the window (the restart is
accepted), a frame of an older epoch is a replay (so captured frames of a dead process stay dead,
and so do its own frames still in flight when it was killed). The scheme needs each sender's wall
clock not to step back across its own restart by more than the restart took. A receiver that itself
restarts has no memory of the windows; with a clock tolerance (step 4) it still refuses every frame
sent before it started (less the tolerance): a frame of an earlier run, or of a peer's life that
ended before it started. What it can be made to accept once more is limited to frames sent during
its own life (and the tolerance before it) by a sender process it has not yet heard from again.
The age of a frame is not held against it once the receiver runs (a receiver busy for seconds
still takes what was queued meanwhile). The tolerance is also a statement about clocks: a sender
whose clock runs ahead of the receiver's by more than it, or behind by more than it at the
receiver's start, is refused as ``stale`` (and :meth:`Gate.clock_offsets` reports the offsets seen,
so the skew is named, not silent).
"""

from __future__ import annotations

import base64
import binascii
import math
import struct
import time
from dataclasses import dataclass
from typing import Mapping

from nacl.bindings import crypto_core_ed25519_is_valid_point
from nacl.exceptions import BadSignatureError
from nacl.signing import SigningKey, VerifyKey

from decentral.errors import ProtocolError
from protocols.messages import BROADCAST, Message, decode

__all__ = [
    "ENVELOPE_MAGIC",
    "ENVELOPE_VERSION",
    "REJECT_REASONS",
    "SIGNATURE_SIZE",
    "Rejected",
    "Opened",
    "ReplayWindow",
    "Signer",
    "Gate",
    "new_private_key",
    "private_key_from_bytes",
    "public_key_bytes",
    "private_key_bytes",
    "b64encode",
    "b64decode_key",
    "check_public_key",
    "envelope_overhead",
    "seal",
    "parse",
]

ENVELOPE_MAGIC = b"DCSE"
ENVELOPE_VERSION = 1
SIGNATURE_SIZE = 64
KEY_SIZE = 32
#: why a frame was refused; the counters in ``TransportStats.rejected`` use exactly these names. The first
#: four are the envelope checks; ``stale`` is a frame sent too long ago (or too far ahead) by the sender's
#: clock, ``rate`` a frame from a connection that sent refused frames, past the budget for checking them,
#: ``unread`` a frame still queued when the receiver closed
REJECT_REASONS = ("bad_signature", "replay", "unknown_sender", "malformed", "stale", "rate", "unread", "oversize")
_PREFIX = struct.Struct("<4sBB")  # magic, version, L
_FIELDS = struct.Struct("<QQdI")  # epoch, seq, sent_at, N
_MAX_NAME = 255


class Rejected(ProtocolError):
    """A frame was refused; :attr:`reason` is one of :data:`REJECT_REASONS`."""

    def __init__(self, reason: str, detail: str):
        assert reason in REJECT_REASONS, reason
        self.reason = reason
        super().__init__(f"{reason}: {detail}")


# ---------------------------------------------------------------------------- keys
def new_private_key() -> SigningKey:
    """A fresh Ed25519 signing key from the operating system's random source (never from a seed)."""
    return SigningKey.generate()


def private_key_from_bytes(raw: bytes) -> SigningKey:
    """The signing key whose 32 raw private bytes (the Ed25519 seed) are ``raw``; ``ValueError`` otherwise."""
    raw = bytes(raw)
    if len(raw) != KEY_SIZE:
        raise ValueError(f"a private key is {KEY_SIZE} bytes, got {len(raw)}")
    return SigningKey(raw)


def private_key_bytes(key: SigningKey) -> bytes:
    """The 32 raw private bytes (the Ed25519 seed) of a signing key."""
    return bytes(key)


def public_key_bytes(key: SigningKey | VerifyKey) -> bytes:
    """The 32 raw bytes of the public key (of a private key's public half)."""
    return bytes(key.verify_key if isinstance(key, SigningKey) else key)


def b64encode(raw: bytes) -> str:
    """Standard base64 text of ``raw`` (how key files and peers files store keys)."""
    return base64.b64encode(raw).decode("ascii")


def check_public_key(raw: bytes) -> bytes:
    """Return ``raw`` if it is a usable Ed25519 public key (a valid point of the main subgroup), else ``ValueError``."""
    if len(raw) != KEY_SIZE or not crypto_core_ed25519_is_valid_point(bytes(raw)):
        raise ValueError("is not a valid Ed25519 public key")
    return raw


def b64decode_key(text: object) -> bytes:
    """The 32 key bytes of a base64 string; ``ValueError`` if it is not exactly that."""
    if not isinstance(text, str):
        raise ValueError("must be a base64 string")
    try:
        raw = base64.b64decode(text.encode("ascii"), validate=True)
    except (binascii.Error, UnicodeEncodeError):
        raise ValueError("is not valid base64") from None
    if len(raw) != KEY_SIZE:
        raise ValueError(f"must decode to {KEY_SIZE} bytes, got {len(raw)}")
    return raw


# ---------------------------------------------------------------------------- envelope
def envelope_overhead(sender: str) -> int:
    """Bytes the envelope adds to an inner frame sent by ``sender``: ``98 + len(UTF-8 name)``."""
    return _PREFIX.size + len(sender.encode("utf-8")) + _FIELDS.size + SIGNATURE_SIZE


def seal(key: SigningKey, sender: str, epoch: int, seq: int, sent_at: float, inner: bytes) -> bytes:
    """Wrap the inner frame ``inner`` in a version-1 envelope signed with ``key`` (layout: module docstring)."""
    name = sender.encode("utf-8")
    if not 1 <= len(name) <= _MAX_NAME:
        raise ProtocolError("sender name must be 1 to 255 UTF-8 bytes")
    body = b"".join((_PREFIX.pack(ENVELOPE_MAGIC, ENVELOPE_VERSION, len(name)), name,
                     _FIELDS.pack(epoch, seq, float(sent_at), len(inner)), inner))
    return body + key.sign(body).signature


@dataclass(frozen=True, slots=True)
class Opened:
    """The parts of an envelope (nothing checked yet but its layout).

    Attributes
    ----------
    sender : str
        The claimed sender.
    epoch, seq : int
        The sender process's epoch and the frame's sequence number.
    sent_at : float
        The sender's clock at sending (s).
    inner : bytes
        The inner message frame.
    signed : bytes
        The bytes the signature covers.
    signature : bytes
        The 64-byte signature.
    """

    sender: str
    epoch: int
    seq: int
    sent_at: float
    inner: bytes
    signed: bytes
    signature: bytes


def parse(frame: bytes) -> Opened:
    """Split an envelope into its parts, checking only its layout.

    Raises
    ------
    Rejected
        ``malformed``: short, bad magic, unknown version, bad name, or a length that is not exactly
        what the header says.
    """
    if len(frame) < _PREFIX.size:
        raise Rejected("malformed", f"{len(frame)} bytes is shorter than an envelope header")
    magic, version, n_name = _PREFIX.unpack_from(frame, 0)
    if magic != ENVELOPE_MAGIC:
        raise Rejected("malformed", "bad magic")
    if version != ENVELOPE_VERSION:
        raise Rejected("malformed", f"unknown envelope version {version}")
    head = _PREFIX.size + n_name + _FIELDS.size
    if n_name == 0 or len(frame) < head + SIGNATURE_SIZE:
        raise Rejected("malformed", "truncated envelope header")
    try:
        sender = frame[_PREFIX.size:_PREFIX.size + n_name].decode("utf-8")
    except UnicodeDecodeError:
        raise Rejected("malformed", "sender name is not UTF-8") from None
    epoch, seq, sent_at, n_inner = _FIELDS.unpack_from(frame, _PREFIX.size + n_name)
    if len(frame) != head + n_inner + SIGNATURE_SIZE:
        expect = head + n_inner + SIGNATURE_SIZE
        raise Rejected("malformed", f"length {len(frame)} does not match the header's {expect}")
    if not math.isfinite(sent_at):
        raise Rejected("malformed", "sent_at is not a finite time")
    end = head + n_inner
    return Opened(sender, epoch, seq, sent_at, bytes(frame[head:end]), bytes(frame[:end]), bytes(frame[end:]))


class Signer:
    """The sending half: one per agent process, numbering and signing its frames.

    Parameters
    ----------
    name : str
        The agent's name (as in the peers file).
    key : nacl.signing.SigningKey
        Its signing key.
    epoch : int, optional
        Defaults to ``time.time_ns()`` at construction (see the module docstring on restarts).
    """

    def __init__(self, name: str, key: SigningKey, epoch: int | None = None):
        self.name = name
        self._key = key
        self.epoch = time.time_ns() if epoch is None else int(epoch)
        self._seq = 0

    def seal(self, message: Message, sent_at: float) -> bytes:
        """The signed envelope of ``message`` (which must name this agent as its sender)."""
        if message.sender != self.name:
            raise ProtocolError(f"agent {self.name!r} cannot send a message from {message.sender!r}")
        frame = seal(self._key, self.name, self.epoch, self._seq, sent_at, message.to_bytes())
        self._seq += 1
        return frame


class ReplayWindow:
    """Anti-replay state for one sender: the newest epoch and a sliding bitmap over its sequence numbers.

    Like the IPsec/DTLS anti-replay window (RFC 4303 §3.4.3, RFC 6347 §4.1.2.6): ``top`` is the
    highest sequence number accepted in the current epoch and bit ``d`` of the bitmap says whether
    ``top - d`` was accepted. A frame is fresh if its epoch is newer (the window restarts), or if it
    has the current epoch and a sequence number above ``top``, or within ``size`` below it and not
    seen yet. Reordering within the window is accepted; each (epoch, seq) is accepted at most once.

    Parameters
    ----------
    size : int
        Number of sequence numbers below the newest one that are still accepted out of order.
    """

    def __init__(self, size: int = 1024):
        if size < 1:
            raise ProtocolError("replay window size must be positive")
        self.size = int(size)
        self.epoch = -1
        self.top = -1
        self._bits = 0
        self._mask = (1 << self.size) - 1

    def fresh(self, epoch: int, seq: int) -> bool:
        """Whether ``(epoch, seq)`` would be accepted now (nothing is remembered)."""
        if epoch != self.epoch:
            return epoch > self.epoch
        d = self.top - seq
        return d < 0 or (d < self.size and not (self._bits >> d) & 1)

    def mark(self, epoch: int, seq: int) -> None:
        """Remember ``(epoch, seq)`` as seen (call only for a fresh pair)."""
        if epoch > self.epoch:
            self.epoch, self.top, self._bits = epoch, seq, 1
        elif seq > self.top:
            shift = seq - self.top
            self._bits = ((self._bits << shift) | 1) & self._mask if shift < self.size else 1
            self.top = seq
        else:
            self._bits |= 1 << (self.top - seq)

    def accept(self, epoch: int, seq: int) -> bool:
        """Whether ``(epoch, seq)`` is fresh; if so, remember it."""
        if not self.fresh(epoch, seq):
            return False
        self.mark(epoch, seq)
        return True


class Gate:
    """The receiving half: checks every inbound frame for one agent (steps 1-8 of the module docstring).

    Parameters
    ----------
    name : str
        The receiving agent.
    public_keys : Mapping[str, bytes]
        Every known sender's raw 32-byte Ed25519 public key (from the peers file).
    window : int
        Replay window size per sender (:class:`ReplayWindow`).
    max_age : float, optional
        Refuse (``stale``) a frame whose ``sent_at`` is more than this many seconds before ``since``;
        None (default) checks no clock.
    max_ahead : float, optional
        ... or more than this many seconds after the receiver's clock (the ``now`` given to
        :meth:`screen`; default: ``max_age``).
    since : float, optional
        The receiver's start on the senders' clock (default: ``time.time()`` when the gate is made).
    """

    def __init__(self, name: str, public_keys: Mapping[str, bytes], window: int = 1024, *,
                 max_age: float | None = None, max_ahead: float | None = None, since: float | None = None):
        self.name = name
        self._keys = {who: VerifyKey(bytes(raw)) for who, raw in public_keys.items()}
        self._window = int(window)
        self._windows: dict[str, ReplayWindow] = {}
        self.max_age = None if max_age is None else float(max_age)
        self.max_ahead = self.max_age if max_ahead is None else float(max_ahead)
        self.since = time.time() if since is None else float(since)
        self._offsets: dict[str, tuple[float, float]] = {}  # sender -> (min, max) of now - sent_at seen

    def admit(self, frame: bytes, now: float | None = None) -> tuple[Opened, Message]:
        """The envelope and its message if ``frame`` passes every check (:meth:`screen`, then :meth:`verify`).

        Raises
        ------
        Rejected
            With the reason of the first failing check.
        """
        env = self.screen(frame, now)
        return env, self.verify(env)

    def screen(self, frame: bytes, now: float | None = None) -> Opened:
        """Checks 1-4 (no signature): the envelope, if it is worth verifying.

        Raises
        ------
        Rejected
            ``malformed``, ``unknown_sender``, ``replay`` or ``stale``.
        """
        env = parse(frame)
        if env.sender not in self._keys:
            raise Rejected("unknown_sender", f"{env.sender!r} is not in the peers file")
        window = self._windows.get(env.sender)
        if window is not None and not window.fresh(env.epoch, env.seq):
            raise Rejected("replay", f"{env.sender!r} epoch {env.epoch} seq {env.seq} is not fresh")
        if now is not None:
            lag = float(now) - env.sent_at
            lo, hi = self._offsets.get(env.sender, (lag, lag))
            self._offsets[env.sender] = (min(lo, lag), max(hi, lag))
            if self.max_age is not None and (env.sent_at < self.since - self.max_age or lag < -self.max_ahead):
                raise Rejected("stale", f"{env.sender!r} sent it {lag:+.3f} s before this clock, "
                                        f"{self.since - env.sent_at:+.3f} s before this receiver started "
                                        f"(tolerance {self.max_age:g} s before the start, {self.max_ahead:g} s ahead)")
        return env

    def own_epoch(self, epoch: int) -> None:
        """Tell the gate the epoch this agent itself sends with (its :class:`Signer`'s).

        Only this process sends as this agent, so a frame in its name from an older epoch is a
        capture of an earlier life of it, refused as ``replay`` before any signature check.
        """
        window = self._windows.setdefault(self.name, ReplayWindow(self._window))
        if epoch > window.epoch:
            window.epoch, window.top, window._bits = int(epoch), -1, 0

    def clock_offsets(self) -> dict[str, tuple[float, float]]:
        """Per claimed sender: the smallest and largest ``now - sent_at`` seen (s), refused frames included.

        The smallest is the sender's clock offset plus the quickest delivery; a value beyond the
        tolerance names a clock (or a start time) that is off. Frames of unknown senders are not kept.
        """
        return dict(self._offsets)

    def verify(self, env: Opened) -> Message:
        """Checks 5-8 on an envelope :meth:`screen` passed: signature, inner frame, sender, receiver.

        Raises
        ------
        Rejected
            ``bad_signature``, ``replay`` or ``malformed``.
        """
        try:
            self._keys[env.sender].verify(env.signed, env.signature)
        except BadSignatureError:
            raise Rejected("bad_signature", f"signature does not verify for {env.sender!r}") from None
        window = self._windows.get(env.sender)
        if window is None:
            window = self._windows[env.sender] = ReplayWindow(self._window)
        if not window.fresh(env.epoch, env.seq):  # checked again: the frame may have been screened long ago
            raise Rejected("replay", f"{env.sender!r} epoch {env.epoch} seq {env.seq} is not fresh")
        try:
            message = decode(env.inner)
        except ProtocolError as err:
            raise Rejected("malformed", f"inner frame: {err}") from None
        if message.sender != env.sender:
            raise Rejected("bad_signature", f"{env.sender!r} signed a message from {message.sender!r}")
        if message.receiver not in (self.name, BROADCAST) or (env.sender == self.name and message.is_broadcast):
            raise Rejected("replay", f"a frame from {env.sender!r} to {message.receiver!r} reached {self.name!r}")
        window.mark(env.epoch, env.seq)  # only a frame admitted whole moves the window
        return message
