"""The `decentral simulate` command."""

import json

import pytest

from sims.cli.main import main
from sims.io.log_json import read_log
from sims.simulation.world.truth import read_truth


def test_simulate_writes_log_and_truth(tmp_path, capsys):
    """simulate writes a readable decentral.log/1 and decentral.truth/1 with the requested steps."""
    out = tmp_path / "run"
    assert main(["simulate", "table1", "-o", str(out), "--steps", "7", "--seed", "3"]) == 0
    log, truth = read_log(out / "log.json"), read_truth(out / "truth.json")
    assert len(log.steps) == 7 and len(truth.poses.times) == 7
    assert truth.meta["scenario"] == "table1" and truth.meta["seed"] == 3


def test_no_noise_and_set_reach_the_scenario(tmp_path):
    """--no-noise and --set KEY=VALUE change the scenario's config."""
    out = tmp_path / "run"
    assert main(["simulate", "multi", "-o", str(out), "--steps", "4", "--no-noise", "--set", "n_assemblies=3"]) == 0
    meta = json.loads((out / "truth.json").read_text())["meta"]["config"]
    assert meta["noise"] is False and meta["n_assemblies"] == 3


@pytest.mark.parametrize(
    "args",
    [["nope"], ["multi", "--set", "n_assemblies=100"], ["multi", "--set", "colour=3"],
     ["table1", "--steps", "0"], ["table1", "--set", "noequals"]],
)
def test_bad_input_exits_2_with_one_line_and_writes_nothing(tmp_path, capsys, args):
    """Bad input gives exit 2, a one-line message naming the field, and no output folder."""
    out = tmp_path / "run"
    assert main(["simulate", args[0], "-o", str(out), *args[1:]]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "error" in err
    assert not out.exists()


def test_output_path_that_is_a_file_is_bad_input(tmp_path, capsys):
    """An OUTDIR that is an existing file is refused with exit 2."""
    out = tmp_path / "file"
    out.write_text("x")
    assert main(["simulate", "single_node", "-o", str(out), "--steps", "2"]) == 2
    assert out.read_text() == "x"


def test_frames_png_writes_frames_and_records_them_in_truth(tmp_path):
    """--frames png writes frames/<assembly>/<camera>/<step>.png and the truth lists what each shows."""
    out = tmp_path / "run"
    assert main(["simulate", "single_node", "-o", str(out), "--steps", "2", "--frames", "png"]) == 0
    assert (out / "frames" / "A0" / "cam0" / "00001.png").is_file()
    truth = read_truth(out / "truth.json")
    (node,) = truth.frames[0]["A0/cam0"]["nodes"]
    assert node["id"] == 10 and node["visible"] == 1.0
