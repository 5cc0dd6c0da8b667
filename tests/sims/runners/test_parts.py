"""An agent's part of a log: its own data only, a valid decentral.log/1, and the parts add up to the log."""

import json

import numpy as np
import pytest

from decentral.errors import InputError
from sims.io.log_json import log_to_dict
from sims.runners.parts import read_part, split_log, write_part
from sims.simulation.scenarios import get_scenario, simulate


@pytest.fixture(scope="module")
def log():
    return simulate(get_scenario("multi", n_assemblies=3, steps=3), seed=1).log


def test_a_part_holds_only_its_owner_data_and_lists_every_assembly(log):
    """Every part lists all assemblies in the log's order but holds its owner's cameras, config, odometry only."""
    for name, part in split_log(log).items():
        assert part.assemblies == log.assemblies
        assert all(cam.assembly == name for cam in part.cameras.values())
        for step in part.steps:
            assert set(step.config) <= {name} and set(step.odometry) <= {name}
            assert all(key.startswith(name + "/") for key in (*step.detections, *step.mounts))


def test_the_parts_add_up_to_the_log(log):
    """Merging every part's steps gives back the log's configuration, odometry and detections."""
    parts = split_log(log)
    for k, step in enumerate(log.steps):
        config = {a: c for p in parts.values() for a, c in p.steps[k].config.items()}
        dets = {key: d for p in parts.values() for key, d in p.steps[k].detections.items()}
        odo = {a: o for p in parts.values() for a, o in p.steps[k].odometry.items()}
        assert config.keys() == step.config.keys() and dets == step.detections and odo.keys() == step.odometry.keys()
        for a in config:
            for node in config[a]:
                assert np.array_equal(config[a][node], step.config[a][node])


def test_a_written_part_reads_back_and_names_its_owner(log, tmp_path):
    """write_part / read_part round trip; the file is a decentral.log/1 with "part": NAME."""
    part = split_log(log)["A1"]
    path = tmp_path / "A1.json"
    write_part(path, part, "A1")
    doc = json.loads(path.read_text())
    assert doc["format"] == "decentral.log/1" and doc["part"] == "A1"
    back = read_part(path, "A1")
    assert log_to_dict(back) == log_to_dict(part)


def test_reading_someone_elses_part_or_a_whole_log_is_refused(log, tmp_path):
    """An agent refuses another agent's part and a log holding other assemblies' data, naming the field."""
    path = tmp_path / "A1.json"
    write_part(path, split_log(log)["A1"], "A1")
    with pytest.raises(InputError, match="part"):
        read_part(path, "A2")
    whole = tmp_path / "log.json"
    whole.write_text(json.dumps(log_to_dict(log)))
    with pytest.raises(InputError, match="steps\\[0\\]|camera"):
        read_part(whole, "A1")


def test_cli_parts_writes_each_assemblys_part_that_its_agent_reads(log, tmp_path):
    """`decentral parts LOG -o DIR` writes NAME.part.json per assembly, each what `read_part` accepts for NAME
    and equal to the log's part; an unknown --only name exits 2 and writes nothing."""
    from sims.cli.main import main
    from sims.io.log_json import write_log

    write_log(tmp_path / "log.json", log)
    assert main(["parts", str(tmp_path / "log.json"), "-o", str(tmp_path / "parts"), "-q"]) == 0
    assert sorted(p.name for p in (tmp_path / "parts").iterdir()) == [f"{n}.part.json" for n in sorted(log.assemblies)]
    for name, expected in split_log(log).items():
        got = read_part(tmp_path / "parts" / f"{name}.part.json", name)
        assert log_to_dict(got) == log_to_dict(expected)
    assert main(["parts", str(tmp_path / "log.json"), "-o", str(tmp_path / "none"), "--only", "A9", "-q"]) == 2
    assert not (tmp_path / "none").exists()
