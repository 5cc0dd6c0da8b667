"""Configuration gossip: owners named from announcements; a relay never overrides the owner; relays answer; own announcements and requests."""

import numpy as np

from protocols.admm_messages import ConfigAnnounce, ConfigRequest
from protocols.config_gossip import ConfigGossip, ConfigTable
from protocols.messages import BROADCAST


def _ann(sender, step, ids, owner="", shift=0.0):
    ids = np.array(ids, dtype=np.int64)
    return ConfigAnnounce(sender=sender, receiver="A0", round=0, step=step, ids=ids,
                          centres=np.column_stack([ids + shift, np.zeros(len(ids)), np.zeros(len(ids))]), owner=owner)


def test_the_latest_configuration_not_after_a_step_names_the_owner():
    """A node moves between assemblies at step 5: step 3 names the old owner, step 6 the new one."""
    table = ConfigTable("A0", ["A0", "A1", "A2"])
    assert table.learn(_ann("A1", 0, [5, 6])) and table.learn(_ann("A2", 5, [6]))
    table.learn(_ann("A1", 5, [5]))
    assert table.owner_of(6, 3)[0] == "A1" and table.owner_of(6, 6)[0] == "A2"
    assert table.owner_of(9, 6) is None


def test_a_relay_never_replaces_the_owners_own_announcement():
    """A relayed copy of a step the owner announced itself changes nothing; for a new step it is taken."""
    table = ConfigTable("A0", ["A0", "A1", "A2"])
    table.learn(_ann("A1", 0, [5]))
    assert not table.learn(_ann("A2", 0, [5], owner="A1", shift=1.0))
    assert table.owner_of(5, 0)[1][0] == 5.0
    assert table.learn(_ann("A2", 2, [5], owner="A1", shift=1.0)) and table.owner_of(5, 2)[1][0] == 6.0


def test_own_and_unknown_assemblies_are_not_kept():
    """Announcements of the holder itself or of an assembly outside the log are ignored."""
    table = ConfigTable("A0", ["A0", "A1"])
    assert not table.learn(_ann("A0", 0, [1])) and not table.learn(_ann("A9", 0, [2]))
    assert len(table) == 0


def test_a_request_is_answered_with_the_held_configurations_that_list_its_nodes():
    """A request for node 6 gets A2's configuration relayed (owner named), not A1's, nor the requester's own."""
    table = ConfigTable("A0", ["A0", "A1", "A2", "A3"])
    table.learn(_ann("A1", 0, [5])), table.learn(_ann("A2", 0, [6, 7])), table.learn(_ann("A3", 0, [6]))
    answers = table.relays(ConfigRequest(sender="A3", receiver="*", round=1, ids=np.array([6])), "A0", 4)
    assert [(m.owner, m.receiver, m.sender) for m in answers] == [("A2", "A3", "A0")]
    assert answers[0].ids.tolist() == [6, 7]


def _own(ids):
    return {i: np.array([float(i), 0.0, 0.0]) for i in ids}


def test_the_own_configuration_is_broadcast_when_it_changes_and_re_announced_to_observers_only():
    """A new configuration is broadcast once; unchanged, it goes every announce_every steps to the observers only."""
    gossip = ConfigGossip("A0", ["A0", "A1", "A2"], announce_every=3)
    first = gossip.set_own(_own([1, 2]), 0, 0, observers=("A1",))
    assert [(m.receiver, m.step) for m in first] == [(BROADCAST, 0)]
    assert gossip.set_own(_own([1, 2]), 1, 5, ("A1",)) == [] and gossip.set_own(_own([1, 2]), 2, 9, ("A1",)) == []
    again = gossip.set_own(_own([1, 2]), 3, 12, observers=("A1", "A2"))
    assert [(m.receiver, m.step) for m in again] == [("A1", 0), ("A2", 0)]  # the step it was broadcast at
    changed = gossip.set_own(_own([1, 2, 3]), 4, 15, observers=("A1",))
    assert [(m.receiver, m.step, m.ids.tolist()) for m in changed] == [(BROADCAST, 4, [1, 2, 3])]


def test_a_request_is_answered_with_the_own_configuration_and_relays():
    """Every agent answers a request with its own configuration, plus the held ones listing a requested node."""
    gossip = ConfigGossip("A0", ["A0", "A1", "A2"], announce_every=5)
    gossip.set_own(_own([1]), 0, 0, ())
    gossip.learn(_ann("A1", 0, [7]))
    out = gossip.answer(ConfigRequest(sender="A2", receiver=BROADCAST, round=3, ids=np.array([7])), 0, 4)
    assert [(m.receiver, m.owner, m.ids.tolist()) for m in out] == [("A2", "", [1]), ("A2", "A1", [7])]
    assert gossip.answer(ConfigRequest(sender="A2", receiver=BROADCAST, round=3, ids=np.array([7])), None, 4)[0].owner


def test_unnamed_nodes_are_requested_until_every_live_configuration_is_in():
    """Unknown nodes are asked for (every 3 rounds at most) until every other, or every live, assembly's configuration is in."""
    gossip = ConfigGossip("A0", ["A0", "A1", "A2"], announce_every=5)
    gossip.unknown = {9}
    assert [m.ids.tolist() for m in gossip.request(10, None)] == [[9]]
    assert gossip.request(12, None) == [] and len(gossip.request(13, None)) == 1
    gossip.learn(_ann("A1", 0, [5]))
    assert gossip.unresolved(None) == {9}
    assert gossip.unresolved({0, 1}) == set()  # A2 not heard from lately: 9 is its own or a stray tag
    gossip.learn(_ann("A2", 0, [6]))
    assert gossip.unresolved(None) == set() and gossip.request(20, None) == []


def test_on_a_slow_link_a_request_is_repeated_only_after_the_round_trip_the_agent_passes():
    """With ``every`` = a measured round trip (here 40 rounds), unknown nodes are asked for again only after it:
    asking sooner only multiplies the answers (every agent answers each request)."""
    gossip = ConfigGossip("A0", ["A0", "A1", "A2"], announce_every=5)
    gossip.unknown = {9}
    assert len(gossip.request(10, None, every=40)) == 1
    assert all(gossip.request(r, None, every=40) == [] for r in range(11, 50))
    assert len(gossip.request(50, None, every=40)) == 1
