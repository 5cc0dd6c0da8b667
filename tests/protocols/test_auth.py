"""Signed envelopes and the replay window: layout, every refusal reason, and anti-replay properties."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocols.auth import (
    ENVELOPE_VERSION,
    Gate,
    Rejected,
    ReplayWindow,
    Signer,
    envelope_overhead,
    new_private_key,
    parse,
    public_key_bytes,
    seal,
)
from protocols.messages import BROADCAST, Heartbeat

KEYS = {name: new_private_key() for name in ("A0", "A1", "A2")}
PUBLIC = {name: public_key_bytes(key) for name, key in KEYS.items()}


def hb(a: str, b: str = BROADCAST, k: int = 0):
    return Heartbeat(sender=a, receiver=b, round=k, t=1.5)


def refusal(gate: Gate, frame: bytes) -> str:
    with pytest.raises(Rejected) as err:
        gate.admit(frame)
    return err.value.reason


def test_envelope_layout_matches_the_documented_offsets():
    """Magic, version, name, epoch, seq, sent_at and inner length sit at the documented offsets; the size
    is inner + 98 + L."""
    inner = hb("A0").to_bytes()
    frame = seal(KEYS["A0"], "A0", 7, 42, 3.25, inner)
    assert frame[:4] == b"DCSE" and frame[4] == ENVELOPE_VERSION and frame[5] == 2 and frame[6:8] == b"A0"
    assert struct.unpack_from("<QQdI", frame, 8) == (7, 42, 3.25, len(inner))
    assert frame[36:36 + len(inner)] == inner
    assert len(frame) == len(inner) + envelope_overhead("A0") == len(inner) + 98 + 2
    env = parse(frame)
    assert (env.sender, env.epoch, env.seq, env.sent_at, env.inner) == ("A0", 7, 42, 3.25, inner)


def test_gate_admits_a_genuine_frame_and_returns_its_message():
    """A frame signed by its sender passes the gate with its message intact."""
    frame = Signer("A0", KEYS["A0"]).seal(hb("A0", "A1", 3), 2.0)
    env, msg = Gate("A1", PUBLIC).admit(frame)
    assert msg == hb("A0", "A1", 3) and env.sender == "A0" and env.sent_at == 2.0


def test_signer_refuses_to_sign_for_another_agent():
    """A signer only seals its own agent's messages."""
    with pytest.raises(Exception, match="cannot send"):
        Signer("A0", KEYS["A0"]).seal(hb("A1"), 0.0)


@pytest.mark.parametrize("cut", [0, 3, 5, 20, 60, -1])
def test_truncated_frames_are_malformed(cut):
    """Any truncation of a genuine envelope is refused as malformed."""
    frame = Signer("A0", KEYS["A0"]).seal(hb("A0"), 0.0)
    assert refusal(Gate("A1", PUBLIC), frame[:cut]) == "malformed"


def test_padded_bad_magic_and_other_versions_are_malformed():
    """Trailing bytes, another magic and an unknown envelope version are refused as malformed."""
    frame = Signer("A0", KEYS["A0"]).seal(hb("A0"), 0.0)
    gate = Gate("A1", PUBLIC)
    assert refusal(gate, frame + b"\x00") == "malformed"
    assert refusal(gate, b"XXXX" + frame[4:]) == "malformed"
    for version in (0, 2, 255):
        assert refusal(gate, frame[:4] + bytes([version]) + frame[5:]) == "malformed"
    assert gate.admit(frame)[1] == hb("A0")  # none of that touched the window


def test_non_finite_send_time_is_malformed():
    """A member's validly signed envelope whose sent_at is NaN or infinite is refused as malformed."""
    for t in (float("nan"), float("inf")):
        assert refusal(Gate("A1", PUBLIC), seal(KEYS["A0"], "A0", 1, 0, t, hb("A0").to_bytes())) == "malformed"


def test_unknown_sender_is_refused():
    """A well-signed frame from a name not in the peers file is refused as unknown_sender."""
    frame = Signer("X", new_private_key()).seal(hb("X"), 0.0)
    assert refusal(Gate("A1", PUBLIC), frame) == "unknown_sender"


def test_wrong_key_and_flipped_bytes_are_bad_signatures():
    """A member's name signed with another key, or a genuine frame with one byte changed, is a bad signature."""
    gate = Gate("A1", PUBLIC)
    assert refusal(gate, Signer("A0", KEYS["A2"]).seal(hb("A0"), 0.0)) == "bad_signature"
    frame = Signer("A0", KEYS["A0"]).seal(hb("A0"), 0.0)
    for pos in (40, len(frame) - 1, len(frame) - 64):
        assert refusal(gate, frame[:pos] + bytes([frame[pos] ^ 1]) + frame[pos + 1:]) == "bad_signature"


def test_a_member_cannot_speak_for_another():
    """A2 signing (with its own valid key) a message that claims to come from A0 is refused as bad_signature."""
    frame = seal(KEYS["A2"], "A2", 1, 0, 0.0, hb("A0").to_bytes())
    assert refusal(Gate("A1", PUBLIC), frame) == "bad_signature"


def test_replays_misdirected_and_reflected_frames_are_replays():
    """The same frame twice, a frame addressed to someone else, and an agent's own broadcast are refused as
    replay (a message an agent sends to itself is not)."""
    signer = Signer("A0", KEYS["A0"])
    gate = Gate("A1", PUBLIC)
    frame = signer.seal(hb("A0"), 0.0)
    gate.admit(frame)
    assert refusal(gate, frame) == "replay"
    assert refusal(gate, signer.seal(hb("A0", "A2"), 0.0)) == "replay"
    assert refusal(gate, Signer("A1", KEYS["A1"]).seal(hb("A1"), 0.0)) == "replay"
    assert gate.admit(Signer("A1", KEYS["A1"], epoch=1).seal(hb("A1", "A1"), 0.0))[1] == hb("A1", "A1")  # to itself


def test_malformed_inner_frame_of_a_member_is_malformed():
    """A validly signed envelope whose inner frame does not decode is refused as malformed."""
    frame = seal(KEYS["A0"], "A0", 1, 0, 0.0, b"not a message")
    assert refusal(Gate("A1", PUBLIC), frame) == "malformed"


def test_restarted_sender_is_accepted_and_its_old_epoch_is_not():
    """A fresh process (newer epoch, seq from 0) is accepted; frames of the old process are then replays."""
    gate = Gate("A1", PUBLIC)
    old = Signer("A0", KEYS["A0"], epoch=100)
    old_frames = [old.seal(hb("A0", k=k), 0.0) for k in range(5)]
    for f in old_frames[:3]:
        gate.admit(f)
    new = Signer("A0", KEYS["A0"], epoch=200)
    gate.admit(new.seal(hb("A0", k=0), 0.0))
    for f in old_frames:
        assert refusal(gate, f) == "replay"


def test_default_epochs_grow_across_restarts():
    """Two signers made one after the other get increasing epochs (the restart rule relies on it)."""
    first = Signer("A0", KEYS["A0"])
    assert Signer("A0", KEYS["A0"]).epoch > first.epoch


@settings(max_examples=60, deadline=None)
@given(st.permutations(list(range(64))), st.lists(st.integers(0, 63), max_size=20))
def test_window_accepts_each_fresh_seq_once_in_any_order(order, repeats):
    """Any permutation of fresh sequence numbers within the window is accepted once; every repeat is refused."""
    w = ReplayWindow(64)
    assert all(w.accept(5, s) for s in order)
    assert not any(w.accept(5, s) for s in order + repeats)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(0, 5000), min_size=1, max_size=200), st.integers(1, 300))
def test_window_never_accepts_a_pair_twice_and_refuses_only_seen_or_too_old(seqs, size):
    """Over any sequence of arrivals, a seq is accepted iff unseen and within ``size`` of the newest accepted."""
    w = ReplayWindow(size)
    seen: set[int] = set()
    for s in seqs:
        top = max(seen) if seen else -1
        expect = s not in seen and (s > top or top - s < size)
        assert w.accept(1, s) == expect
        if expect:
            seen.add(s)


def test_window_survives_reordering_of_a_lossy_burst():
    """Out-of-order arrival within the window (a shuffled burst with gaps) is accepted in full."""
    rng = np.random.default_rng(0)
    seqs = rng.permutation(np.flatnonzero(rng.random(2000) < 0.7))
    w = ReplayWindow(4096)
    assert all(w.accept(9, int(s)) for s in seqs)


GENUINE = Signer("A0", KEYS["A0"], epoch=3).seal(hb("A0", "A1", 9), 1.0)


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=400))
def test_any_byte_string_is_refused_never_raised(data):
    """Arbitrary bytes are refused with one of the four reasons; no other exception ever escapes the gate."""
    with pytest.raises(Rejected) as err:
        Gate("A1", PUBLIC).admit(data)
    assert err.value.reason in ("malformed", "unknown_sender", "bad_signature")


@settings(max_examples=300, deadline=None)
@given(st.integers(0, len(GENUINE) - 1), st.integers(1, 255), st.integers(0, len(GENUINE)))
def test_every_flipped_byte_and_every_cut_of_a_genuine_frame_is_refused(pos, xor, cut):
    """Changing any byte of a genuine frame, or cutting it anywhere, gets it refused (and the original still passes)."""
    gate = Gate("A1", PUBLIC)
    for bad in (GENUINE[:pos] + bytes([GENUINE[pos] ^ xor]) + GENUINE[pos + 1:], GENUINE[:cut] if cut < len(GENUINE)
                else GENUINE + b"\x00"):
        with pytest.raises(Rejected):
            gate.admit(bad)
    assert gate.admit(GENUINE)[1] == hb("A0", "A1", 9)
