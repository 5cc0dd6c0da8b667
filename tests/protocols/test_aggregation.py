"""Tree aggregation bookkeeping: parent choice, the tree a known graph gives, and one window's up/down flow."""

import networkx as nx
from hypothesis import given, settings
from hypothesis import strategies as st

from protocols.aggregation import DownRepair, NeighbourTree, TreeAggregation, choose_parent, tree_from_edges


def test_parent_is_the_neighbour_with_the_smallest_hop_ties_to_the_smallest_index():
    """choose_parent: smallest hop wins, equal hops go to the smaller index, own hop is one more."""
    assert choose_parent({4: 2, 7: 1, 3: 1}, limit=10) == (3, 2)


def test_no_route_means_no_parent():
    """No neighbour heard, unknown hops (-1) or hops at the limit (counting to infinity) give no parent."""
    assert choose_parent({}, limit=5) == (None, None)
    assert choose_parent({1: -1, 2: 4, 3: 7}, limit=5) == (None, None)


def test_tree_from_a_ring_counts_hops_both_ways_round():
    """On a 6-ring rooted at 0 the hops are 0,1,2,3,2,1 and node 3 hangs under the smaller of 2 and 4."""
    hops, parents = tree_from_edges([(i, (i + 1) % 6) for i in range(6)], 6, 0)
    assert [hops[i] for i in range(6)] == [0, 1, 2, 3, 2, 1]
    assert parents == {1: 0, 2: 1, 3: 2, 4: 5, 5: 0}


@st.composite
def connected_graphs(draw):
    n = draw(st.integers(2, 24))
    seed = draw(st.integers(0, 10_000))
    extra = draw(st.integers(0, 2 * n))
    tree = nx.random_labeled_tree(n, seed=seed)
    g = nx.gnm_random_graph(n, extra, seed=seed + 1)
    g.add_edges_from(tree.edges)
    return n, sorted(g.edges)


@settings(max_examples=60, deadline=None)
@given(connected_graphs())
def test_the_known_graph_tree_is_what_the_distance_vector_chooses(graph):
    """Every agent's parent from tree_from_edges equals choose_parent over its neighbours' BFS hops."""
    n, edges = graph
    hops, parents = tree_from_edges(edges, n, 0)
    assert set(hops) == set(range(n))
    g = nx.Graph(edges)
    for a in range(1, n):
        assert choose_parent({b: hops[b] for b in g[a]}, n) == (parents[a], hops[a])


@settings(max_examples=60, deadline=None)
@given(connected_graphs())
def test_parent_pointers_reach_the_root_without_a_loop(graph):
    """Following parents from any agent reaches the root in exactly its hop count of steps."""
    n, edges = graph
    hops, parents = tree_from_edges(edges, n, 0)
    for a in range(n):
        at, steps = a, 0
        while at != 0:
            at, steps = parents[at], steps + 1
            assert steps <= n
        assert steps == hops[a]


def _agg(me, parent, children=(), root=False, total=4, wait=6):
    return TreeAggregation(me, total, root=root, parent=parent, children=children, start=0, wait=wait, hop=1)


def test_the_bundle_up_waits_for_every_expected_child():
    """With its own record but one of two children missing, nothing is due; once both reported, one bundle."""
    a = _agg(1, parent=0, children={2, 3})
    a.add({1: "own"}, forward=True)
    a.add({2: "r2"}, child=2)
    assert not a.up_due(1)
    a.add({3: "r3"}, child=3)
    assert a.up_due(1) and a.take_up(1) == [1, 2, 3]
    assert not a.up_due(2)


def test_after_the_wait_what_it_has_goes_up_and_a_late_child_follows_as_an_update():
    """A silent child is not waited for beyond `wait` rounds; its late record goes up alone."""
    a = _agg(1, parent=0, children={2}, wait=3)
    a.add({1: "own"}, forward=True)
    assert not a.up_due(2)
    assert a.up_due(3) and a.take_up(3) == [1]
    a.add({2: "late"}, child=2)
    assert a.up_due(4) and a.take_up(4) == [2]


def test_records_heard_outside_the_subtree_do_not_go_up():
    """A record that came by broadcast (not from a child) is held but not forwarded to the parent."""
    a = _agg(1, parent=0)
    a.add({1: "own"}, forward=True)
    a.add({3: "broadcast"})
    assert a.take_up(0) == [1] and set(a.records) == {1, 3}


def test_an_unacknowledged_bundle_goes_up_again_every_few_rounds():
    """No acknowledgement `ack_every` rounds after the bundle up: resend due, with every forwarded record."""
    a = _agg(1, parent=0, children={2})
    a.add({1: "own"}, forward=True)
    a.add({2: "r2"}, child=2)
    a.take_up(0)
    assert not a.resend_due(2, ack_every=3, down_every=9)
    assert a.resend_due(3, ack_every=3, down_every=9) and a.take_resend(3) == [1, 2]
    assert a.unanswered == 2


def test_after_the_acknowledgement_only_a_missing_down_bundle_triggers_a_resend():
    """Acknowledged (the parent holds all it was sent): the next resend waits `down_every` rounds; never once final."""
    a = _agg(1, parent=0)
    a.add({1: "own"}, forward=True)
    a.take_up(0)
    a.acknowledge([0, 1], 1)
    assert a.acknowledged and a.unanswered == 0
    assert not a.resend_due(5, ack_every=3, down_every=5)
    assert a.resend_due(6, ack_every=3, down_every=5)
    a.final = True
    assert not a.resend_due(20, ack_every=3, down_every=5)


def test_an_acknowledgement_missing_a_record_does_not_count():
    """A parent's list that lacks a record sent up is no acknowledgement."""
    a = _agg(1, parent=0, children={2})
    a.add({1: "own"}, forward=True)
    a.add({2: "r2"}, child=2)
    a.take_up(0)
    a.acknowledge([1], 1)
    assert not a.acknowledged


def test_the_root_never_sends_up_and_is_complete_with_every_record():
    """The root owes nothing up; it is complete when it holds all agents' records."""
    r = _agg(0, parent=None, root=True, total=3)
    r.add({0: "own"}, forward=True)
    r.add({1: "a", 2: "b"}, child=1)
    assert not r.up_due(10) and r.complete
    assert r.down_targets() == [1]


def test_a_convergecast_and_broadcast_over_a_tree_sends_at_most_one_up_and_one_down_per_child():
    """On a random 30-agent tree with instant delivery the root completes, all agents end with every
    record, and each agent sends 1 bundle up and 1 per child down."""
    n = 30
    edges = sorted(nx.random_labeled_tree(n, seed=3).edges)
    hops, parents = tree_from_edges(edges, n, 0)
    kids = {a: {b for b, p in parents.items() if p == a} for a in range(n)}
    aggs = {a: TreeAggregation(a, n, root=a == 0, parent=parents.get(a), children=kids[a], start=0, wait=100,
                               hop=hops[a]) for a in range(n)}
    sent = {a: 0 for a in range(n)}
    for a in aggs.values():
        a.add({a.me: f"r{a.me}"}, forward=True)
    queue = []
    for rnd in range(2 * n):
        for a in aggs.values():
            if a.up_due(rnd):
                queue.append(("up", a.me, a.parent, {i: a.records[i] for i in a.take_up(rnd)}))
                sent[a.me] += 1
            if a.root and a.complete and not a.final:
                a.final = True
                for c in a.down_targets():
                    queue.append(("down", 0, c, dict(a.records)))
                    sent[0] += 1
        now, queue = queue, []
        for kind, src, dst, recs in now:
            if kind == "up":
                aggs[dst].add(recs, child=src)
            elif not aggs[dst].final:
                aggs[dst].add(recs)
                aggs[dst].final = True
                for c in aggs[dst].down_targets(exclude=(src,)):
                    queue.append(("down", dst, c, dict(aggs[dst].records)))
                    sent[dst] += 1
    assert all(a.complete and a.final for a in aggs.values())
    assert all(sent[a] == (0 if a == 0 else 1) + len(kids[a]) for a in range(n))


def test_down_repair_resends_to_a_silent_child_after_grace_then_every_few_rounds_at_most_tries_times():
    """A child never heard from gets the down bundle again from start + grace, every `every` rounds, `tries` times."""
    repair = DownRepair([4], start=10, round_index=8, every=3, tries=2, grace=2)
    sent = [r for r in range(8, 30) if repair.due(r, lambda child: False)]
    assert sent == [12, 15] and repair  # still pending, but no more resends


def test_down_repair_drops_children_heard_from_or_acknowledging():
    """A child heard in the window's ADMM or acknowledging the bundle is never resent to; order is by index."""
    repair = DownRepair([7, 2, 5], start=0, round_index=0)
    repair.have(5)
    repair.have(None)  # an acknowledgement from an unknown sender changes nothing
    assert repair.due(3, lambda child: child == 7) == [2]
    assert sorted(repair.pending) == [2]
    assert repair.due(6, lambda child: True) == [] and not repair


def test_neighbour_tree_chooses_the_parent_among_recent_entries_only():
    """A neighbour last heard long ago (and in an older window) no longer counts: the parent is the best recent one."""
    tree = NeighbourTree(["A0", "A1", "A2", "A3"], me=3, root=0, fresh_rounds=10)
    tree.heard("A1", 1, 0, 0, 0)  # the better hop, but heard at round 0 in window 0
    tree.heard("A2", 2, 1, 95, 5)
    assert tree.position(100, 5) == (2, 3)
    assert tree.position(5, 5) == (1, 2)  # still fresh at round 5
    assert tree.position(100, 1) == (1, 2)  # heard in the window before this one


def test_neighbour_tree_root_and_children():
    """The root has hop 0 and no parent; children are the recent entries naming this agent as parent."""
    root = NeighbourTree(["A0", "A1", "A2"], me=0, root=0, fresh_rounds=10)
    root.heard("A1", 1, 0, 50, 3)
    root.heard("A2", 1, 1, 50, 3)
    assert root.position(50, 3) == (None, 0)
    assert root.children(50, 3) == {1}
    root.drop("A1")
    assert root.children(50, 3) == set()


def test_neighbour_tree_learnt_from_a_graph_keeps_only_adjacent_agents():
    """learn fills every neighbour's place from the view graph and forgets agents no longer adjacent."""
    tree = NeighbourTree(["A0", "A1", "A2", "A3"], me=2, root=0, fresh_rounds=10)
    tree.heard("A3", 1, 0, 0, 0)
    tree.learn({(1, 0), (2, 1), (3, 2)}, 40, 4)
    assert tree.entries == {"A1": (1, 0, 40, 4), "A3": (3, 2, 40, 4)}
    assert tree.position(40, 4) == (1, 2)
