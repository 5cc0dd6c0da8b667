"""Cheap refusal first: what the gate refuses without a signature check, the clock tolerance, and the budget."""

from __future__ import annotations

import time

import pytest
import zmq

from protocols.admission import SuspectBudget
from protocols.auth import Gate, Rejected, Signer, new_private_key, public_key_bytes, seal
from protocols.messages import BROADCAST, Heartbeat
from protocols.zmq_transport import open_loopback

KEYS = {name: new_private_key() for name in ("A0", "A1")}
PUBLIC = {name: public_key_bytes(key) for name, key in KEYS.items()}


def hb(a: str, k: int = 0):
    return Heartbeat(sender=a, receiver=BROADCAST, round=k, t=0.0)


class CountingGate(Gate):
    """A gate that counts the signature checks it makes."""

    checks = 0

    def verify(self, env):
        type(self).checks += 1
        return super().verify(env)


def reason(fn) -> str:
    with pytest.raises(Rejected) as err:
        fn()
    return err.value.reason


def test_stale_sequence_and_unknown_sender_are_refused_without_a_signature_check():
    """A replayed (epoch, seq), an older epoch and an unknown name are refused by screen(): no check made."""
    gate = CountingGate("A1", PUBLIC)
    signer = Signer("A0", KEYS["A0"], epoch=100)
    first = signer.seal(hb("A0"), 0.0)
    gate.admit(first)
    CountingGate.checks = 0
    flipped = first[:-1] + bytes([first[-1] ^ 1])  # a bad signature, but a seen (epoch, seq)
    assert reason(lambda: gate.admit(flipped)) == "replay"
    older = seal(KEYS["A1"], "A0", 99, 7, 0.0, hb("A0").to_bytes())  # wrong key, older epoch
    assert reason(lambda: gate.admit(older)) == "replay"
    stranger = seal(KEYS["A0"], "EVE", 1, 0, 0.0, hb("EVE").to_bytes())
    assert reason(lambda: gate.admit(stranger)) == "unknown_sender"
    assert CountingGate.checks == 0


def test_frames_of_an_earlier_run_are_refused_by_a_fresh_receiver():
    """A genuine frame sent 60 s ago (an earlier run, same keys) is stale to a receiver that never heard its sender."""
    now = time.time()
    old = Signer("A0", KEYS["A0"], epoch=int((now - 70) * 1e9)).seal(hb("A0"), now - 60)
    assert reason(lambda: Gate("A1", PUBLIC, max_age=5.0).admit(old, now)) == "stale"
    fresh = Signer("A0", KEYS["A0"]).seal(hb("A0"), now - 0.1)
    assert Gate("A1", PUBLIC, max_age=5.0).admit(fresh, now)[1] == hb("A0")
    assert Gate("A1", PUBLIC).admit(old, now)[1] == hb("A0")  # without a tolerance: nothing tells it is old


def test_skewed_clocks_are_refused_and_reported():
    """A sender whose clock is 8 s ahead is refused as stale and its offset is reported by clock_offsets()."""
    gate = Gate("A1", PUBLIC, max_age=5.0)
    now = time.time()
    frames = [Signer("A0", KEYS["A0"]).seal(hb("A0", k), now + 8.0) for k in range(3)]
    assert {reason(lambda f=f: gate.admit(f, now)) for f in frames} == {"stale"}
    lo, hi = gate.clock_offsets()["A0"]
    assert -8.01 < lo <= hi < -7.99


def test_own_name_from_an_older_epoch_is_a_replay():
    """A frame in the receiver's own name from before its own epoch (a capture of its earlier life) is a replay."""
    gate = CountingGate("A1", PUBLIC)
    gate.own_epoch(500)
    CountingGate.checks = 0
    old = Signer("A1", KEYS["A1"], epoch=400).seal(hb("A1"), 0.0)
    assert reason(lambda: gate.admit(old)) == "replay" and CountingGate.checks == 0


def test_the_budget_refills_at_its_rate_and_charges_large_frames_more():
    """Checks are spent one per frame plus one per 64 KiB, refilled at `rate` per second up to `burst`."""
    t = [0.0]
    budget = SuspectBudget(rate=10, burst=10, clock=lambda: t[0])
    assert sum(budget.take(0) for _ in range(50)) == 10
    t[0] = 0.5
    assert sum(budget.take(0) for _ in range(50)) == 5
    t[0] = 10.0
    assert budget.take(9 * 65536) and not budget.take(0)  # 10 checks at once, then none


def test_a_flood_of_forged_frames_costs_a_bounded_number_of_checks_and_legit_frames_pass():
    """5,000 forged frames on one connection: at most burst + rate x elapsed are verified, the rest are `rate`,
    each is counted, and a genuine frame sent after them is delivered."""
    nets, table = open_loopback(["A0", "A1"])
    ctx = zmq.Context()
    push = ctx.socket(zmq.PUSH)
    push.setsockopt(zmq.SNDHWM, 0)
    push.connect(table["A1"].address)
    wrong = new_private_key()
    try:
        t0 = time.monotonic()
        for i in range(5000):
            push.send(seal(wrong, "A0", 2**63 + i, i, 0.0, hb("A0", i).to_bytes()))
        nets["A0"].send(Heartbeat(sender="A0", receiver="A1", round=1, t=0.0), 0.0)
        got, deadline = [], time.monotonic() + 60
        while (not got or sum(nets["A1"].stats().rejected.values()) < 5000) and time.monotonic() < deadline:
            nets["A1"].wait(0.01)
            got += nets["A1"].poll("A1", 0.0)
        elapsed = time.monotonic() - t0
        rejected = dict(nets["A1"].stats().rejected)
        assert [d.message.round for d in got] == [1]
        assert sum(rejected.values()) == 5000
        assert rejected["bad_signature"] <= 1 + 50 + 200 * elapsed and rejected["rate"] >= 5000 - 51 - 200 * elapsed
    finally:
        push.close(linger=0)
        ctx.term()
        for net in nets.values():
            net.close()


def test_frames_queued_at_close_are_counted_as_unread():
    """Frames still queued on the inbound socket when the transport closes are counted, not lost silently."""
    nets, table = open_loopback(["A0", "A1"])
    try:
        for k in range(30):
            nets["A0"].send(Heartbeat(sender="A0", receiver="A1", round=k, t=0.0), 0.0)
        deadline = time.monotonic() + 10
        while nets["A1"]._local["A1"].socket.poll(10) == 0 and time.monotonic() < deadline:
            pass
        time.sleep(0.2)
    finally:
        for net in nets.values():
            net.close()
    assert nets["A1"].stats().rejected.get("unread") == 30
