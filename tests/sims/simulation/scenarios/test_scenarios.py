"""Properties of the simulated runs of every scenario."""

import numpy as np
import pytest

from sims.io.log_json import log_to_dict, parse_log
from sims.simulation.scenarios import SCENARIOS, get_scenario, simulate
from sims.simulation.world.shapes import NODE_RADIUS

SHORT = {"table1": 25, "reconfig": 125, "multi": 12, "single_node": 10}


def _sim(name, seed=0, **params):
    params.setdefault("steps", SHORT.get(name, 10))
    return simulate(get_scenario(name, **params), seed=seed)


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_log_is_a_valid_contract_log(name):
    """Every scenario's log passes the contract reader and survives a round trip unchanged."""
    log = _sim(name).log
    doc = log_to_dict(log)
    assert log_to_dict(parse_log(doc)) == doc


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_noiseless_detections_back_project_to_true_centres(name):
    """Without noise, seed eq. (1) applied to every detection gives the true node centre."""
    sim = _sim(name, noise=False)
    world, log = sim.world, sim.log
    n = 0
    for k, step in enumerate(log.steps):
        ids, _, centres = world.nodes_in_world(k)
        where = {int(i): c for i, c in zip(ids, centres)}
        for rig in world.cameras:
            cam = world.camera_in_world(rig, k)
            K = log.cameras[rig.key].K
            for d in step.detections[rig.key]:
                pc = np.linalg.solve(K, [d.u, d.v, 1.0]) * K[0, 0] * log.node_radius / d.r  # seed eq. (1)
                assert np.allclose(cam.apply(pc), where[d.node], atol=1e-9)
                n += 1
    assert n > 0 or name == "single_node"


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_same_seed_same_run_other_seed_other_run(name):
    """A run is a function of its seed."""
    a, b, c = (log_to_dict(_sim(name, seed=s).log) for s in (5, 5, 6))
    assert a == b
    assert a != c or name == "single_node"


def test_noise_flag_turns_every_sensor_exact():
    """noise=False gives exact odometry (no missing steps) and no drop-outs."""
    sim = _sim("table1", noise=False)
    assert all(len(s.odometry) == 4 for s in sim.log.steps[1:])
    for step, vis in zip(sim.log.steps, sim.truth.visible):
        assert len(step.detections["A0/cam0"]) == len(vis["A0/cam0"])


def test_table1_geometry_matches_the_seed_setting():
    """Table I: observer root on a 0.75 m table, three targets of distinct shapes, 1.85 m away on average."""
    sim = _sim("table1", steps=150)
    p = sim.truth.poses.p
    assert np.allclose(p["A0"][:, 2], 0.75 + NODE_RADIUS)
    targets = ["A1", "A2", "A3"]
    dist = np.stack([np.linalg.norm(p[t][:, :2] - p["A0"][:, :2], axis=1) for t in targets])
    assert dist.min() > 0.6 and dist.max() < 3.0
    # the paper's Table I implies 1.8-2.1 m observer-target distance (0.039 m is 2.09 %, 0.112 m 5.38 %)
    mean3d = np.mean([np.linalg.norm(p[t] - p["A0"], axis=1).mean() for t in targets])
    assert 1.7 < mean3d < 2.1
    shapes = {tuple(np.round(sim.world.assembly(t).shapes[0].centres, 3).ravel()) for t in targets}
    assert len(shapes) == 3
    assert sim.log.steps[1].t - sim.log.steps[0].t == pytest.approx(0.2)


def test_reconfig_changes_configuration_and_hides_nodes():
    """The reconfig target goes through several configurations, and a node is hidden then seen again."""
    sim = _sim("reconfig")
    configs = {tuple(sorted((n, tuple(c)) for n, c in s.config["A1"].items())) for s in sim.log.steps}
    assert len(configs) >= 5
    seen = [{v["id"] for v in vis["A0/cam0"]} for vis in sim.truth.visible]
    present = [set(s.config["A1"]) for s in sim.log.steps]
    hidden = [k for k in range(len(seen)) if present[k] - seen[k]]
    assert hidden and any(seen[k] >= present[k] for k in range(hidden[0], len(seen)))


def test_multi_view_graph_is_a_cycle():
    """In the multi scenario each assembly's camera sees the next assembly around the ring."""
    for n in (2, 5):
        sim = _sim("multi", n_assemblies=n, noise=False)
        for i in range(n):
            owner = sim.log.steps[0].node_owner()
            seen = {owner[d.node] for s in sim.log.steps for d in s.detections[f"A{i}/cam0"]}
            assert f"A{(i + 1) % n}" in seen


def test_multi_announces_the_mount_change():
    """The first observer's strut turn appears as a mount override from mid-run on."""
    sim = _sim("multi", steps=10)
    assert not sim.log.steps[4].mounts and "A0/cam0" in sim.log.steps[5].mounts


def test_single_node_target_never_moves():
    """The single_node target is one node and stands still."""
    sim = _sim("single_node")
    assert all(len(s.config["A1"]) == 1 for s in sim.log.steps)
    assert np.ptp(sim.truth.poses.p["A1"], axis=0).max() == 0
