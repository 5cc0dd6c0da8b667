"""PeerClock: a late or restarted agent learns the run's START from its peers' frames, never from one member alone."""

from types import SimpleNamespace

from protocols.messages import Heartbeat
from sims.runners.agent_run import PeerClock


def _arrival(sender, round_index, sent_at):
    return SimpleNamespace(message=Heartbeat(sender=sender, receiver="A2", round=round_index, t=0.0), sent_at=sent_at)


def test_two_peers_that_agree_give_the_start():
    """Frames of two senders whose rounds imply the same START (within a round period) give that START."""
    clock = PeerClock(round_period=0.025)
    clock.observe([_arrival("A0", 400, 110.0), _arrival("A1", 401, 110.03)])
    assert abs(clock.start() - 100.0) < 0.03


def test_one_sender_alone_cannot_move_the_clock():
    """A single member's frames (or two that disagree) give no START."""
    clock = PeerClock(round_period=0.025)
    clock.observe([_arrival("A0", 400, 110.0)])
    assert clock.start() is None
    clock.observe([_arrival("A1", 10, 110.0)])  # implies 109.75: not within a round period of 100
    assert clock.start() is None


def test_round_zero_queries_do_not_count():
    """A round-0 heartbeat is a question about the clock, not an answer."""
    clock = PeerClock(round_period=0.025)
    clock.observe([_arrival("A0", 0, 110.0), _arrival("A1", 0, 110.0)])
    assert clock.start() is None
