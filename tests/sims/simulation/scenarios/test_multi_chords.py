"""The multi ring with chord cameras: a cyclic view graph that is not a ring."""

import pytest

from sims.simulation.scenarios import get_scenario, simulate


def _edges(sim, k=1):
    owner = sim.log.steps[k].node_owner()
    return {(key, owner[d.node]) for key, dets in sim.log.steps[k].detections.items() for d in dets
            if owner.get(d.node) not in (None, key.split("/")[0])}


def test_chord_cameras_watch_across_the_ring():
    """With chord_every=2, assemblies 0, 2, 4 carry cam1 and it sees the assembly two places ahead."""
    sim = simulate(get_scenario("multi", n_assemblies=6, steps=2, chord_every=2), seed=1)
    assert {c.key for c in sim.log.cameras.values() if c.key.endswith("/cam1")} == {"A0/cam1", "A2/cam1", "A4/cam1"}
    edges = _edges(sim)
    assert {("A0/cam1", "A2"), ("A2/cam1", "A4"), ("A4/cam1", "A0")} <= edges


def test_without_chords_there_is_one_camera_per_assembly():
    """The default ring keeps one camera per assembly (the chord option changes nothing when off)."""
    sim = simulate(get_scenario("multi", n_assemblies=5, steps=2), seed=1)
    assert all(key.endswith("/cam0") for key in sim.log.cameras)


@pytest.mark.parametrize("kw", [{"chord_every": -1}, {"chord_skip": 1}])
def test_bad_chord_parameters_are_rejected(kw):
    """A negative chord period or a skip below 2 raises."""
    with pytest.raises(ValueError):
        get_scenario("multi", n_assemblies=6, steps=2, **kw)
