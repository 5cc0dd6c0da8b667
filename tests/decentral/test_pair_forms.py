"""An observer's own factors (decentral.pair_forms): exact back-projection, own nodes skipped, pair forms per window and per step."""

import numpy as np

from decentral.factors import NoiseModel
from decentral.geometry import rotz
from decentral.pair_forms import own_detections, pair_forms
from tests.synthetic import camera, make_log

WORLD = {"A0": [(0.0, np.zeros(3))], "A1": [(0.4, np.array([1.2, 0.1, 0.0]))]}
CONFIGS = {"A0": {1: np.array([0.0, 0.0, 0.05])}, "A1": {7: np.array([0.1, 0.0, 0.05]), 8: np.array([-0.1, 0.1, 0.05])}}


def test_noiseless_detections_back_project_to_the_true_centres_in_the_root_frame():
    """Exact circles give each seen node's centre in the observer's root frame (Liu et al. 2024 eq. (1), (4)), weight > 0."""
    cam = camera("A0")
    log = make_log(WORLD, CONFIGS, [cam])
    out = own_detections([cam], log.steps[0].detections, {}, {1}, log.node_radius, NoiseModel())
    assert sorted(node for node, _, _ in out) == [7, 8]
    yaw, p = WORLD["A1"][0]
    for node, t, w in out:
        assert np.allclose(t, rotz(yaw) @ CONFIGS["A1"][node] + p, atol=1e-9) and w > 0


def test_detections_of_own_nodes_are_skipped():
    """A node the observer owns itself carries no relative information: it is left out."""
    cam = camera("A0")
    log = make_log(WORLD, CONFIGS, [cam])
    out = own_detections([cam], log.steps[0].detections, {}, {1, 7}, log.node_radius, NoiseModel())
    assert [node for node, _, _ in out] == [8]


def _facts(rng, steps=(3, 4, 5)):
    return [(k, rng.normal(size=3), rng.normal(size=3), float(rng.uniform(0.5, 2.0))) for k in steps for _ in range(3)]


def test_the_window_form_is_the_sum_of_the_step_forms():
    """At any poses, the pair's window cost equals the sum of its per-step costs (the shared forms lose nothing)."""
    rng = np.random.default_rng(4)
    window, steps = pair_forms("A0", "A1", _facts(rng))
    assert [p.keys for p in steps] == [(("A0", k), ("A1", k)) for k in (3, 4, 5)]
    theta = dict(zip(window.keys, rng.uniform(-np.pi, np.pi, window.n)))
    pos = dict(zip(window.keys, rng.normal(size=(window.n, 3))))
    total = sum(p.cost(np.array([theta[k] for k in p.keys]), np.array([pos[k] for k in p.keys])) for p in steps)
    assert np.isclose(window.cost(np.array([theta[k] for k in window.keys]), np.array([pos[k] for k in window.keys])),
                      total, rtol=1e-10)


def test_a_steps_form_depends_on_that_steps_facts_alone():
    """Adding a newer step's facts leaves the older steps' forms bit-identical (a window adds one step of forms)."""
    rng = np.random.default_rng(5)
    facts = _facts(rng, steps=(3, 4))
    _, before = pair_forms("A0", "A1", facts)
    _, after = pair_forms("A0", "A1", facts + _facts(rng, steps=(5,)))
    for a, b in zip(before, after):
        assert a.keys == b.keys and np.array_equal(a.M, b.M) and np.array_equal(a.b_z, b.b_z) and a.c_z == b.c_z
