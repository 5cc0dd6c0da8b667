"""Round trip and validation of the decentral.truth/1 format."""

import json

import numpy as np
import pytest

from decentral.errors import InputError
from sims.simulation.scenarios import get_scenario, simulate
from sims.simulation.world.truth import parse_truth, read_truth, truth_to_dict, write_truth


def test_truth_round_trips_through_json(tmp_path):
    """Writing then reading a truth file gives back the same poses, times and visibility."""
    truth = simulate(get_scenario("multi", steps=6, n_assemblies=3), seed=4).truth
    write_truth(tmp_path / "truth.json", truth)
    back = read_truth(tmp_path / "truth.json")
    assert np.array_equal(back.poses.times, truth.poses.times)
    for name in truth.poses.R:
        assert np.allclose(back.poses.R[name], truth.poses.R[name])
        assert np.allclose(back.poses.p[name], truth.poses.p[name])
    assert back.visible == truth.visible and back.reference == "A0"
    assert json.loads((tmp_path / "truth.json").read_text())["format"] == "decentral.truth/1"


def test_truth_with_wrong_format_names_the_field():
    """A document of another format is refused with the field 'format'."""
    with pytest.raises(InputError) as err:
        parse_truth({"format": "decentral.log/1", "steps": []})
    assert err.value.field == "format"


def test_truth_missing_an_assembly_pose_names_the_step():
    """A step without one assembly's pose is refused, naming that step."""
    doc = truth_to_dict(simulate(get_scenario("single_node", steps=3), seed=0).truth)
    del doc["steps"][2]["poses"]["A1"]
    with pytest.raises(InputError) as err:
        parse_truth(doc)
    assert err.value.field == "steps[2].poses"


def test_truth_with_non_finite_position_is_refused():
    """A NaN in a position is bad input naming the field."""
    doc = truth_to_dict(simulate(get_scenario("single_node", steps=3), seed=0).truth)
    doc["steps"][1]["poses"]["A0"]["p"][0] = float("nan")
    with pytest.raises(InputError) as err:
        parse_truth(doc)
    assert err.value.field.startswith("steps[1].poses.A0.p")
