"""The assembly agent: config checks, message handling, and the ADMM message flow."""

import subprocess
import sys

import numpy as np
import pytest

from agents.assembly import AgentConfig, AssemblyAgent
from decentral.errors import InputError, ProtocolError
from protocols.admm_messages import ConfigAnnounce, ConfigRequest
from protocols.messages import BROADCAST, AdmmDual, AdmmPrimal, decode
from sims.admm_run import own_step
from sims.scenarios import get_scenario, simulate


@pytest.fixture(scope="module")
def log():
    return simulate(get_scenario("multi", n_assemblies=3, steps=2), seed=1).log


def _agent(log, name):
    cams = tuple(c for c in log.cameras.values() if c.assembly == name)
    return AssemblyAgent(AgentConfig(name=name, assemblies=log.assemblies, reference="A0", cameras=cams,
                                     node_radius=log.node_radius))


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
    assert agent._targets_z["A1"].values[0][1][0] == 2.0


def test_agents_do_not_import_the_simulator_or_ground_truth():
    """Importing the agent loads neither sims (where ground truth lives) nor cv2/pettingzoo."""
    code = "import sys, agents.assembly; print(any(m == 'sims' or m.startswith(('sims.', 'cv2', 'pettingzoo')) for m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
