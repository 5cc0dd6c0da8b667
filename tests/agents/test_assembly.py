"""The assembly agent: config checks, message handling, and the ADMM message flow."""

import subprocess
import sys

import numpy as np
import pytest

from agents.assembly import AgentConfig, AssemblyAgent
from decentral.errors import InputError, ProtocolError
from protocols.admm_messages import ConfigAnnounce, ConfigRequest, FactorShare, pack_forms
from protocols.messages import BROADCAST, AdmmDual, AdmmPrimal, decode
from protocols.delta_messages import DeltaBundle, FactorDelta, JointPoses
from sims.runners.admm_run import own_step
from sims.simulation.scenarios import get_scenario, simulate

OWN_FORMS = (FactorShare, FactorDelta)  # an agent's own forms: admm.factors, or compactly admm.factors_delta


@pytest.fixture(scope="module")
def log():
    return simulate(get_scenario("multi", n_assemblies=3, steps=2), seed=1).log


def _agent(log, name, share_forms="never"):
    cams = tuple(c for c in log.cameras.values() if c.assembly == name)
    return AssemblyAgent(AgentConfig(name=name, assemblies=log.assemblies, reference="A0", cameras=cams,
                                     node_radius=log.node_radius, share_forms=share_forms))


def _observed(log, name):
    """An assembly that `name` detects at step 0."""
    owner = log.steps[0].node_owner()
    for key, dets in log.steps[0].detections.items():
        if key.startswith(name + "/"):
            for d in dets:
                if owner.get(d.node) not in (None, name):
                    return owner[d.node]
    raise AssertionError("no detection")


def test_config_rejects_foreign_cameras_and_unknown_names(log):
    """An agent may hold only its own cameras, and its name and reference must be listed."""
    with pytest.raises(InputError):
        AgentConfig(name="A0", assemblies=log.assemblies, reference="A0", cameras=(log.cameras["A1/cam0"],))
    with pytest.raises(InputError):
        AgentConfig(name="Z", assemblies=log.assemblies, reference="A0")


def test_config_messages_round_trip_and_reject_corruption():
    """admm.config and admm.config_request decode to equal messages; a flipped byte is a ProtocolError."""
    a = ConfigAnnounce(sender="A1", receiver=BROADCAST, round=3, step=2, ids=np.array([4, 5]),
                       centres=np.array([[0.0, 0.1, 0.2], [0.3, 0.4, 0.5]]))
    b = ConfigRequest(sender="A0", receiver=BROADCAST, round=1, ids=np.array([7]))
    for m in (a, b):
        assert decode(m.to_bytes()) == m
        frame = bytearray(m.to_bytes())
        frame[-3] ^= 0xFF
        with pytest.raises(ProtocolError):
            decode(bytes(frame))


def test_first_step_announces_the_configuration(log):
    """On its first step an agent broadcasts its own node ids and centres."""
    agent = _agent(log, "A1")
    agent.on_step(own_step(log, "A1", 0))
    out = agent.outbox()
    ann = [m for m in out if isinstance(m, ConfigAnnounce)]
    assert len(ann) == 1 and ann[0].receiver == BROADCAST
    assert set(ann[0].ids.tolist()) == set(log.steps[0].config["A1"])


def test_unknown_nodes_are_requested_then_the_pair_talks_to_its_target(log):
    """Detections of unannounced nodes trigger a config request; after the announcement the pair sends admm.dual."""
    target = _observed(log, "A0")
    agent = _agent(log, "A0")
    agent.on_step(own_step(log, "A0", 0))
    agent.outbox()
    agent.tick(0)
    assert any(isinstance(m, ConfigRequest) for m in agent.outbox())
    other = _agent(log, target)
    other.on_step(own_step(log, target, 0))
    agent.handle(next(m for m in other.outbox() if isinstance(m, ConfigAnnounce)))
    agent.tick(1)  # phase 1 of round 0
    agent.tick(1)  # phase 0 of round 1: the pair iterates
    duals = [m for m in agent.outbox() if isinstance(m, AdmmDual)]
    assert [m.receiver for m in duals] == [target]
    assert duals[0].blocks["x"].shape[1] == 8 and duals[0].blocks["meta"][0] == 1.0  # the reference is in gauge
    assert duals[0].blocks["w"].shape == (duals[0].blocks["x"].shape[0], 7)  # its penalty metric rides along


def _announced(log, names):
    """Agents for `names` that have heard each other's configuration announcements at step 0."""
    agents = {n: _agent(log, n, share_forms="first") for n in names}
    for a in agents.values():
        a.on_step(own_step(log, a.name, 0))
    anns = [m for a in agents.values() for m in a.outbox() if isinstance(m, ConfigAnnounce)]
    for a in agents.values():
        for m in anns:
            if m.sender != a.name:
                a.handle(m)
    return agents


def test_cold_start_broadcasts_the_pair_forms_and_waits_for_everyone(log):
    """At step 0 an agent broadcasts its pair forms (admm.factors_delta: every form, nothing was broadcast before) and
    sends no ADMM value until all forms are in."""
    agent = _announced(log, log.assemblies)["A0"]
    agent.tick(0)
    out = agent.outbox()
    shares = [m for m in out if isinstance(m, OWN_FORMS)]
    assert len(shares) == 1 and shares[0].receiver == BROADCAST and shares[0].step == 0
    assert isinstance(shares[0], FactorDelta) and shares[0].have.tolist() == [0] and len(shares[0].carried()) >= 1
    assert shares[0].digest[0] == len(shares[0].carried())  # the whole record
    assert not any(isinstance(m, (AdmmDual, AdmmPrimal)) for m in out)


def _first_shares(log):
    """Announced agents after their first tick: the agents and A0's broadcast share (A1's outbox drained)."""
    agents = _announced(log, log.assemblies)
    for a in agents.values():
        a.tick(0)
    a0 = [m for m in agents["A0"].outbox() if isinstance(m, OWN_FORMS)][0]
    agents["A1"].outbox()
    return agents, a0


def test_an_agent_missing_from_a_share_answers_with_its_own_forms(log):
    """An agent whose index is absent from a received share's `have` answers that sender directly."""
    agents, a0 = _first_shares(log)
    agents["A1"].handle(a0)
    reply = [m for m in agents["A1"].outbox() if isinstance(m, OWN_FORMS)]
    assert len(reply) == 1 and reply[0].receiver == "A0"


def test_answers_to_a_share_are_not_answered_again(log):
    """A unicast answer that lacks the receiver does not trigger another answer (no ping-pong)."""
    agents, a0 = _first_shares(log)
    agents["A1"]._sharing.share = None  # A1 is done: its answer lists only itself, so it lacks A0
    agents["A1"].handle(a0)
    answer = [m for m in agents["A1"].outbox() if isinstance(m, OWN_FORMS)][0]
    assert 0 not in answer.have.tolist()
    agents["A0"].outbox()
    agents["A0"].handle(answer)
    assert not [m for m in agents["A0"].outbox() if isinstance(m, OWN_FORMS)]


def test_after_the_shared_cold_start_every_agent_holds_the_same_joint_solution(log):
    """Once every agent has every form, all seed the same consensus poses (bit-identical joint solve)."""
    agents = _announced(log, log.assemblies)
    for a in agents.values():
        a.tick(0)
    shares = [m for a in agents.values() for m in a.outbox() if isinstance(m, OWN_FORMS)]
    for a in agents.values():
        for m in shares:
            if m.sender != a.name:
                a.handle(m)
        a.tick(0)
        a.tick(1)
    seeds = [a._start.seeds for a in agents.values()]
    assert seeds[0] and all(s.keys() == seeds[0].keys() for s in seeds)
    for key in seeds[0]:
        for s in seeds[1:]:
            assert np.array_equal(s[key][0], seeds[0][key][0]) and np.array_equal(s[key][1], seeds[0][key][1])
    assert np.allclose(seeds[0][("A0", 0)][0], np.eye(2)) and np.allclose(seeds[0][("A0", 0)][1], 0)


def test_factor_share_round_trips_and_rejects_inconsistent_lengths():
    """admm.factors decodes to an equal message with the same forms; forms that do not fit `keys` are refused."""
    M = np.arange(36.0).reshape(6, 6)
    M = M + M.T
    keys, flat = pack_forms([(((0, 3), (2, 3)), M, np.array([1.0, 2.0]), 0.5, 6)])
    msg = FactorShare(sender="A0", receiver=BROADCAST, round=2, step=3, have=[0, 2], keys=keys, forms=flat,
                      pin=[3, 0.0, 0.0, 0.0, 0.1])
    back = decode(msg.to_bytes())
    assert back == msg
    (k, M2, b, c, count), = back.unpack()
    assert k == ((0, 3), (2, 3)) and np.array_equal(M2, M) and b.tolist() == [1.0, 2.0] and c == 0.5
    with pytest.raises(ProtocolError):
        FactorShare(sender="A0", receiver=BROADCAST, round=2, step=3, have=[0], keys=keys, forms=flat[:-1], pin=[])


def test_a_config_request_for_own_nodes_is_answered(log):
    """An agent answers a request naming one of its nodes with a unicast announcement."""
    agent = _agent(log, "A2")
    agent.on_step(own_step(log, "A2", 0))
    agent.outbox()
    node = next(iter(log.steps[0].config["A2"]))
    agent.handle(ConfigRequest(sender="A1", receiver=BROADCAST, round=0, ids=np.array([node])))
    out = agent.outbox()
    assert len(out) == 1 and isinstance(out[0], ConfigAnnounce) and out[0].receiver == "A1"


def test_older_or_duplicate_admm_values_do_not_replace_newer_ones(log):
    """A reordered (older round) admm.primal is ignored; the newest value per neighbour is kept."""
    agent = _agent(log, "A0")
    agent.on_step(own_step(log, "A0", 0))

    def primal(r, x):
        row = np.array([[0, 1, 0, 0, 1, x, 0, 0]], float)
        return AdmmPrimal(sender="A1", receiver="A0", round=r, window=0,
                          blocks={"x": row, "meta": np.array([1.0, 0, 0, r])})

    agent.handle(primal(5, 2.0))
    agent.handle(primal(3, 9.0))
    agent.handle(primal(5, 9.0))
    assert agent._inbox.targets["A1"].values[0][1][0] == 2.0


def test_messages_from_a_sender_outside_the_log_are_ignored_and_harmless(log):
    """ADMM values (with a tree entry) and a joint solution from a name that is not an assembly of the log are
    counted as ignored and leave the agent able to run its rounds."""
    agent = _agent(log, "A0", share_forms="every")
    agent.on_step(own_step(log, "A0", 0))
    row = np.array([[0, 1, 0, 0, 1, 0.5, 0, 0]], float)
    agent.handle(AdmmPrimal(sender="Z9", receiver="A0", round=1, window=0,
                            blocks={"x": row, "meta": np.array([1.0, 0, 0, 1]), "tree": np.array([1.0, 0.0])}))
    before = agent.counters["ignored"]
    agent.handle(AdmmDual(sender="Z9", receiver="A0", round=1, window=0, blocks={"tree": np.array([1.0, 0.0])}))
    assert agent.counters["ignored"] == before + 1 >= 2
    for r in range(1, 4):
        agent.tick(r, 0)
        agent.tick(r, 1)
    assert "Z9" not in agent.neighbours


def test_agents_do_not_import_the_simulator_or_ground_truth():
    """Importing the agent loads neither sims (where ground truth lives) nor cv2/pettingzoo."""
    code = "import sys, agents.assembly; print(any(m == 'sims' or m.startswith(('sims.', 'cv2', 'pettingzoo')) for m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def _drive(agents, step, log, rounds):
    """Run `agents` through log step `step` for `rounds` rounds, delivering every message by the next phase."""
    names = list(agents)
    sent = []
    inbox = {n: [] for n in names}

    def post(msgs):
        for m in msgs:
            sent.append(m)
            for r in (names if m.receiver == BROADCAST else [m.receiver]):
                if r != m.sender:
                    inbox[r].append(m)

    for a in agents.values():
        a.on_step(own_step(log, a.name, step))
        post(a.outbox())
    start = 100 * step
    for r in range(start, start + rounds):
        for _phase in (0, 1):
            now = {n: inbox[n] for n in names}
            for n in names:
                inbox[n] = []
            for n in names:
                for m in now[n]:
                    agents[n].handle(m)
                agents[n].tick(r)
                post(agents[n].outbox())
    return sent


def _tree_agents(log):
    agents = {n: _agent(log, n, share_forms="every") for n in log.assemblies}
    cold = _drive(agents, 0, log, 12)
    return agents, cold


def test_after_a_complete_window_the_forms_go_up_the_tree_not_by_broadcast(log):
    """Step 0 broadcasts (no routes yet); at step 1 each non-reference agent sends one admm.bundle up, to its
    parent (the neighbour nearest the reference), nobody broadcasts, and all seed the same joint solution."""
    agents, cold = _tree_agents(log)
    assert any(isinstance(m, OWN_FORMS) and m.receiver == BROADCAST for m in cold)
    sent = _drive(agents, 1, log, 12)
    assert not any(m.receiver == BROADCAST for m in sent)
    ups = [m for m in sent if isinstance(m, DeltaBundle)]
    assert sorted(m.sender for m in ups) == sorted(n for n in log.assemblies if n != "A0")
    for m in ups:
        assert m.receiver == log.assemblies[agents[m.sender]._parent] and m.hop >= 1
    # the reference solves, the others start from its solution of the newest step (float32 on the wire)
    root = agents["A0"]._start.seeds
    newest = {key: v for key, v in root.items() if key[1] == 1}
    for a in list(agents.values())[1:]:
        assert a._start.seeds.keys() == newest.keys()
        for key, (R, p) in newest.items():
            assert np.allclose(a._start.seeds[key][1], p, atol=1e-5) and np.allclose(a._start.seeds[key][0], R, atol=1e-6)


def test_a_bundle_from_below_after_the_window_is_answered_with_the_down_bundle(log):
    """A child's resend that reaches a parent already done with the window (the down bundle was lost) gets
    the window's solution again, directly."""
    agents, _ = _tree_agents(log)
    sent = _drive(agents, 1, log, 12)
    up = next(m for m in sent if isinstance(m, DeltaBundle))
    parent = agents[up.receiver]
    parent.outbox()
    parent.handle(up)
    answer = parent.outbox()
    assert len(answer) == 1 and isinstance(answer[0], JointPoses)  # the complete set's solution, compactly
    assert answer[0].receiver == up.sender and answer[0].indices("members") == list(range(len(log.assemblies)))


def test_a_broadcast_from_its_parent_turns_a_tree_agent_to_broadcasting(log):
    """A parent that broadcasts its forms has no route: its child stops waiting for the tree and broadcasts too."""
    agents, _ = _tree_agents(log)
    child = next(a for a in agents.values() if a._parent is not None)
    parent = log.assemblies[child._parent]
    child.on_step(own_step(log, child.name, 1))
    child.tick(200)
    child.outbox()
    assert child._sharing.share.mode == "tree"
    other = agents[parent]
    other.on_step(own_step(log, parent, 1))
    other._sharing.tree.entries, other._parent, other._hop = {}, None, None  # as if restarted: no route
    other._sharing.share.agg.parent = other._sharing.share.agg.root = None
    other.tick(200)
    share = next(m for m in other.outbox() if isinstance(m, OWN_FORMS) and m.receiver == BROADCAST)
    child.handle(share)
    child.tick(201)
    child.tick(202)
    assert child._sharing.share.mode == "broadcast"
    assert any(isinstance(m, OWN_FORMS) and m.receiver == BROADCAST for m in child.outbox())


def test_configuration_is_re_announced_to_observers_only(log):
    """An unchanged configuration is re-announced every `announce_every` steps to the current observers
    by unicast, never broadcast again."""
    agents, cold = _tree_agents(log)
    assert sum(isinstance(m, ConfigAnnounce) and m.receiver == BROADCAST for m in cold) == len(log.assemblies)
    a = agents["A1"]
    observers = set(a.observers)
    assert observers
    a.on_step(own_step(log, "A1", 1))
    assert not [m for m in a.outbox() if isinstance(m, ConfigAnnounce)]
    a._configs._reannounced -= a.config.announce_every
    a.on_step(own_step(log, "A1", 1))
    anns = [m for m in a.outbox() if isinstance(m, ConfigAnnounce)]
    assert {m.receiver for m in anns} == observers


def test_a_request_for_another_assemblys_nodes_is_relayed_and_never_overrides_the_owner(log):
    """An agent holding A2's configuration answers a request for A2's nodes with a relay naming A2; the
    requester uses it, but a relayed copy of a step it already has from A2 itself changes nothing."""
    agents = _announced(log, log.assemblies)
    node = next(iter(log.steps[0].config["A2"]))
    agents["A1"].outbox()
    agents["A1"].handle(ConfigRequest(sender="A0", receiver=BROADCAST, round=0, ids=np.array([node])))
    answers = [m for m in agents["A1"].outbox() if isinstance(m, ConfigAnnounce)]
    relays = [m for m in answers if m.owner]
    assert len(relays) == 1 and relays[0].owner == "A2" and relays[0].receiver == "A0" and node in relays[0].ids
    # and its own configuration, so that a requester holding every one can tell a stray tag
    assert [m.receiver for m in answers if not m.owner] == ["A0"]
    fresh = _agent(log, "A0")
    fresh.on_step(own_step(log, "A0", 0))
    fresh.handle(relays[0])
    assert node in fresh._configs.table["A2"][-1][1]
    forged = ConfigAnnounce(sender="A1", receiver="A0", round=1, step=relays[0].step, ids=relays[0].ids,
                            centres=relays[0].centres + 1.0, owner="A2")
    agents["A0"].handle(forged)
    assert np.array_equal(agents["A0"]._configs.table["A2"][-1][1][node], log.steps[0].config["A2"][node])


def test_an_agent_that_cannot_name_a_node_does_not_report_convergence_until_every_configuration_is_in(log):
    """While the configuration of an assembly it sees never reaches it (every copy lost), an observer keeps
    asking for it and never reports convergence (the joint solution it would report lacks that pair); once
    the configuration arrives it names the node and converges."""
    observer = "A0"
    target = _observed(log, observer)
    agents = {n: _agent(log, n, share_forms="every") for n in log.assemblies}
    withheld = []

    def lost(m):
        return (isinstance(m, ConfigAnnounce) and m.receiver in (observer, BROADCAST)
                and (m.owner or m.sender) == target)

    def deliver(messages, hold):
        for m in messages:
            if hold and lost(m):
                withheld.append(m)
                continue
            for a in agents.values():
                if a.name != m.sender and m.receiver in (a.name, BROADCAST):
                    a.handle(m)

    for a in agents.values():
        a.on_step(own_step(log, a.name, 0))
    deliver([m for a in agents.values() for m in a.outbox()], hold=True)
    requests = 0
    for r in range(60):
        for _phase in (0, 1):
            out = []
            for a in agents.values():
                a.tick(r)
                out += a.outbox()
            requests += sum(isinstance(m, ConfigRequest) and m.sender == observer for m in out)
            deliver(out, hold=True)
        assert not agents[observer].converged
    assert requests >= 10 and agents[observer]._unresolved()
    deliver([m for m in withheld if m.sender == target][:1], hold=False)
    for r in range(60, 400):
        for _phase in (0, 1):
            out = []
            for a in agents.values():
                a.tick(r)
                out += a.outbox()
            deliver(out, hold=False)
        if all(a.converged for a in agents.values()):
            break
    assert not agents[observer]._unresolved() and target in agents[observer]._pairs
    assert all(a.converged for a in agents.values())


def test_a_parent_that_cannot_rebuild_a_delta_gets_the_records_whole():
    """A parent that lost the forms a delta builds on (its cache emptied) does not acknowledge those members;
    the child sends them whole (a delta carrying every form) and every agent still starts from the same solution."""
    log = simulate(get_scenario("multi", n_assemblies=3, steps=3), seed=1).log
    agents, _ = _tree_agents(log)
    _drive(agents, 1, log, 12)
    for a in agents.values():
        a._sharing.forms.clear()
    sent = _drive(agents, 2, log, 20)
    deltas = [m for m in sent if isinstance(m, DeltaBundle)]
    assert deltas and any(len(m.owners) == int(m.digest[:, 0].sum()) > len(m.members) for m in deltas)
    root = agents["A0"]._start.seeds
    assert any(key[1] == 2 for key in root)
    for a in list(agents.values())[1:]:
        for key, (R, p) in root.items():
            if key[1] == 2:
                assert np.allclose(a._start.seeds[key][1], p, atol=1e-5)


def test_an_exact_window_answers_with_its_joint_solution_whatever_rows_a_busy_neighbour_sends(log):
    """An exact window (every agent's forms) that ran ADMM rounds to answer a neighbour still without the set keeps
    the joint solution as its estimate: the neighbour's iterate rows in the gossip table are not the answer."""
    from protocols.pose_gossip import pose_row

    agents, _ = _tree_agents(log)
    _drive(agents, 1, log, 12)
    root = agents["A0"]
    assert root._exact() and root.converged
    exact = root.estimates()
    other = next(n for n in exact)
    i = log.assemblies.index(other)
    R, p = root._start.seeds[(other, 1)]
    root._gossip.fill([pose_row(i, 1, root._round + 1, R, p + np.array([0.08, -0.05, 0.0]))], root._round + 1)
    root._start.admm_ran = True  # (it ran rounds to answer that neighbour)
    after = root.estimates()
    assert set(after) == set(exact)
    for name, pose in exact.items():
        assert np.allclose(after[name].p, pose.p, atol=1e-9) and abs(after[name].theta - pose.theta) < 1e-9


def test_an_agent_whose_process_runs_late_shares_by_broadcast_until_it_is_on_time_again(log):
    """The slow-tree test counts a hop as the measured lag plus how late the agent's process ran (the runtime's
    report, in rounds): on time it keeps the tree; a report longer than the wait for the forms switches it to
    broadcast; it stays there until LATE_WINDOWS reports in a row are on time again."""
    from agents.assembly import LATE_WINDOWS

    agent = _agent(log, "A1", share_forms="every")
    agent.on_step(own_step(log, "A1", 0), 0)
    agent.tick(1, 0)
    assert agent.sharing == "tree"
    agent.ran_late(0.5)
    agent.tick(2, 0)
    assert agent.sharing == "tree"
    agent.ran_late(agent.waits["share_timeout"] + 1.0)
    agent.tick(3, 0)
    assert agent.sharing == "broadcast"
    for k in range(LATE_WINDOWS - 1):
        agent.ran_late(0.0)
        agent.tick(4 + k, 0)
        assert agent.sharing == "broadcast"
    agent.ran_late(0.0)
    agent.tick(4 + LATE_WINDOWS, 0)
    assert agent.sharing == "tree"
