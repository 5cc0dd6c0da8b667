"""``decentral localize``: the contract's output, and every bad input ends in one line and exit 2."""

import copy
import json
import subprocess
import sys

import numpy as np
import pytest

from decentral.metrics import estimate_gap
from sims.cli.main import main
from sims.io.log_json import log_to_dict, read_estimate
from tests.synthetic import camera, circle_motion, l_config, line_config, make_log


@pytest.fixture(scope="module")
def good_doc():
    n = 6
    world = {"A0": [(0.0, np.array([0.02 * k, 0.0, 0.81])) for k in range(n)],
             "A1": circle_motion(n, (2.0, 0.0), 0.3, 0.0, 0.05, 0.06)}
    configs = {"A0": line_config([0, 1]), "A1": l_config([5, 6, 7])}
    return log_to_dict(make_log(world, configs, [camera("A0")]))


def write(tmp_path, doc, name="log.json"):
    path = tmp_path / name
    path.write_text(json.dumps(doc) if not isinstance(doc, str) else doc)
    return path


def test_localize_writes_a_contract_estimate(tmp_path, good_doc):
    """A valid log gives exit 0 and a decentral.estimate/1 with A1 placed at every step but the first."""
    out = tmp_path / "est.json"
    assert main(["localize", str(write(tmp_path, good_doc)), "-o", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["format"] == "decentral.estimate/1" and doc["reference"] == "A0"
    assert all("A1" in s["poses"] for s in doc["steps"])
    assert doc["stats"]["all_certified"] is True
    assert read_estimate(out).steps[0].poses["A1"].p.shape == (3,)


def test_bearing_estimator_is_selectable(tmp_path, good_doc):
    """--estimator bearing runs the baseline and says so in stats."""
    out = tmp_path / "est.json"
    assert main(["localize", str(write(tmp_path, good_doc)), "-o", str(out), "--estimator", "bearing"]) == 0
    assert json.loads(out.read_text())["stats"]["estimator"] == "bearing"


def mutate(doc, path, value):
    doc = copy.deepcopy(doc)
    *head, last = path
    node = doc
    for key in head:
        node = node[key]
    if value is DELETE:
        del node[last]
    else:
        node[last] = value
    return doc


DELETE = object()
CAM = ["assemblies", "A0", "cameras", "cam0"]
BAD = {
    "wrong format": (["format"], "decentral.log/0", "format"),
    "missing steps": (["steps"], DELETE, "steps"),
    "negative radius": (["node_radius"], -0.06, "node_radius"),
    "nan radius": (["node_radius"], "NaN", "node_radius"),
    "singular K": (CAM + ["K"], [[0, 0, 0], [0, 760, 384], [0, 0, 1]], "K"),
    "not a rotation": (CAM + ["cam_in_strut", "R"], [[1, 0, 0], [0, 1, 0], [0, 0, 2]], "cam_in_strut.R"),
    "reflection": (CAM + ["strut_in_root", "R"], [[1, 0, 0], [0, 1, 0], [0, 0, -1]], "strut_in_root.R"),
    "short p": (CAM + ["strut_in_root", "p"], [0, 0], "strut_in_root.p"),
    "time goes back": (["steps", 2, "t"], 0.0, "steps[2].t"),
    "undeclared camera": (["steps", 1, "detections"], {"A0/cam9": []}, "A0/cam9"),
    "missing radius": (["steps", 1, "detections", "A0/cam0", 0, "r"], DELETE, ".r"),
    "zero radius": (["steps", 1, "detections", "A0/cam0", 0, "r"], 0, ".r"),
    "string u": (["steps", 1, "detections", "A0/cam0", 0, "u"], "611", ".u"),
    "undeclared assembly": (["steps", 0, "config", "B9"], {"99": [0, 0, 0]}, "config.B9"),
    "bad dtheta": (["steps", 1, "odometry", "A1", "dtheta"], None, "dtheta"),
    "non-integer node id": (["steps", 0, "config", "A1", "x"], [0, 0, 0], "config.A1.x"),
    "odometry on the first step": (["steps", 0, "odometry"], {"A1": {"dp": [0.01, 0, 0], "dtheta": 0.0}},
                                   "steps[0].odometry"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_input_exits_2_naming_file_and_field(tmp_path, good_doc, capsys, case):
    """Each contract bad input: exit 2, one stderr line naming the file and field, no output file."""
    path, value, field = BAD[case]
    doc = mutate(good_doc, path, value)
    text = json.dumps(doc).replace('"NaN"', "NaN")
    log = write(tmp_path, text)
    out = tmp_path / "est.json"
    assert main(["localize", str(log), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(log) in err and field in err, err
    assert not out.exists() and not list(tmp_path.glob(".est.json*"))


@pytest.mark.parametrize("content", ["", "{not json", "[1, 2]", "\x00\x01"])
def test_unreadable_or_malformed_files_exit_2(tmp_path, content, capsys):
    """Empty, malformed or non-object JSON files are rejected with exit 2."""
    out = tmp_path / "est.json"
    assert main(["localize", str(write(tmp_path, content)), "-o", str(out)]) == 2
    assert "log.json" in capsys.readouterr().err and not out.exists()


def test_admm_share_forms_every_matches_the_centralized_estimate(tmp_path, good_doc):
    """`--mode admm --share-forms every` writes the centralized answer (to 1 mm / 0.05 deg) and says so in stats."""
    log, central, admm = write(tmp_path, good_doc), tmp_path / "c.json", tmp_path / "a.json"
    assert main(["localize", str(log), "-o", str(central)]) == 0
    assert main(["localize", str(log), "-o", str(admm), "--mode", "admm", "--share-forms", "every",
                 "--max-rounds", "100"]) == 0
    assert json.loads(admm.read_text())["stats"]["admm"]["share_forms"] == "every"
    dp, dth, mismatched = estimate_gap(read_estimate(central), read_estimate(admm))
    assert mismatched == 0 and dp < 1e-3 and np.degrees(dth) < 0.05


@pytest.mark.parametrize("aggregation", ["tree", "broadcast"])
def test_admm_aggregation_is_selectable_and_recorded(tmp_path, good_doc, aggregation):
    """`--aggregation tree|broadcast` reaches the agents (recorded in stats) and both give the centralized answer."""
    log, central, admm = write(tmp_path, good_doc), tmp_path / "c.json", tmp_path / "a.json"
    assert main(["localize", str(log), "-o", str(central)]) == 0
    assert main(["localize", str(log), "-o", str(admm), "--mode", "admm", "--aggregation", aggregation]) == 0
    assert json.loads(admm.read_text())["stats"]["admm"]["aggregation"] == aggregation
    dp, dth, mismatched = estimate_gap(read_estimate(central), read_estimate(admm))
    assert mismatched == 0 and dp < 1e-3 and np.degrees(dth) < 0.05


def test_missing_file_and_bad_options_exit_2(tmp_path, good_doc, capsys):
    """A missing log, an unknown reference or a bad window exit 2 with one line."""
    out = tmp_path / "est.json"
    assert main(["localize", str(tmp_path / "nope.json"), "-o", str(out)]) == 2
    log = write(tmp_path, good_doc)
    assert main(["localize", str(log), "-o", str(out), "--reference", "Z9"]) == 2
    assert main(["localize", str(log), "-o", str(out), "--window", "0"]) == 2
    assert main(["localize", str(log), "-o", str(out), "--mode", "admm", "--max-rounds", "0"]) == 2
    assert main(["localize", str(log), "-o", str(tmp_path / "no" / "dir.json")]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 5
    assert not out.exists()


def test_console_script_prints_no_traceback(tmp_path):
    """Run as a process, bad input prints one line and no Python traceback."""
    log = write(tmp_path, {"format": "decentral.log/1"})
    proc = subprocess.run([sys.executable, "-m", "sims.cli.main", "localize", str(log), "-o", str(tmp_path / "e.json")],
                          capture_output=True, text=True)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr and len(proc.stderr.strip().splitlines()) == 1


CONTRACT_EXAMPLE = {
    "format": "decentral.log/1", "node_radius": 0.06,
    "assemblies": {"A0": {"cameras": {"cam0": {
        "K": [[760, 0, 512], [0, 760, 384], [0, 0, 1]],
        "strut_in_root": {"R": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "p": [0.09, 0.02, 0.0]},
        "cam_in_strut": {"R": [[0, 0, 1], [-1, 0, 0], [0, -1, 0]], "p": [0.05, 0.0, 0.04]}}}},
        "A1": {}},
    "steps": [
        {"t": 0.0, "config": {"A0": {"0": [0, 0, 0], "1": [0.2, 0, 0]},
                              "A1": {"5": [0, 0, 0], "6": [0.2, 0, 0], "7": [0.2, 0.2, 0]}},
         "detections": {"A0/cam0": [{"id": 5, "u": 611.2, "v": 402.9, "r": 23.1}]}},
        {"t": 0.2, "config": {"A0": {"0": [0, 0, 0], "1": [0.2, 0, 0]},
                              "A1": {"5": [0, 0, 0], "6": [0.2, 0, 0], "7": [0.2, 0.2, 0]}},
         "odometry": {"A0": {"dp": [0.01, 0.0, 0.0], "dtheta": 0.002}, "A1": {"dp": [0.02, 0.001, 0.0], "dtheta": -0.01}},
         "detections": {"A0/cam0": [{"id": 5, "u": 613.0, "v": 401.7, "r": 23.2},
                                    {"id": 7, "u": 650.4, "v": 398.2, "r": 22.0}]}},
    ],
}


@pytest.mark.parametrize("mode", ["centralized", "admm"])
def test_contract_example_leaves_an_undetermined_yaw_out(tmp_path, mode):
    """The one-node example log: one node seen at t=0 leaves A1's yaw open, so A1 is left out there, placed at t=0.2."""
    out = tmp_path / "est.json"
    assert main(["localize", str(write(tmp_path, CONTRACT_EXAMPLE)), "-o", str(out), "--mode", mode]) == 0
    steps = json.loads(out.read_text())["steps"]
    assert steps[0]["poses"] == {} and set(steps[1]["poses"]) == {"A1"}


def test_both_modes_count_the_same_stray_tags_in_stats(tmp_path):
    """A detection whose id no assembly holds (docs/formats.md) is counted in stats.stray_detections by both modes."""
    doc = copy.deepcopy(CONTRACT_EXAMPLE)
    doc["steps"][0]["detections"]["A0/cam0"].append({"id": 99, "u": 300.0, "v": 380.0, "r": 20.0})
    doc["steps"][1]["detections"]["A0/cam0"] += [{"id": 42, "u": 200.0, "v": 380.0, "r": 20.0},
                                                  {"id": 99, "u": 300.0, "v": 380.0, "r": 20.0}]
    log = write(tmp_path, doc)
    counts = []
    for mode in ("centralized", "admm"):
        out = tmp_path / f"{mode}.json"
        assert main(["localize", str(log), "-o", str(out), "--mode", mode]) == 0
        counts.append(json.loads(out.read_text())["stats"]["stray_detections"])
    assert counts == [3, 3]


@pytest.mark.parametrize("argv,option", [
    (["--mode", "admm", "--estimator", "bearing"], "--estimator"),
    (["--mode", "admm", "--solver", "sdp"], "--solver"),
    (["--estimator", "bearing", "--solver", "sdp"], "--solver"),
    (["--loss", "0.1"], "--loss"),
    (["--seed", "3"], "--seed"),
    (["--share-forms", "first"], "--share-forms"),
    (["--aggregation", "broadcast"], "--aggregation"),
    (["--mode", "centralized", "--max-rounds", "10"], "--max-rounds"),
])
def test_an_option_of_the_other_mode_is_refused_not_ignored(tmp_path, good_doc, capsys, argv, option):
    """An option that the chosen mode (or estimator) would ignore: exit 2, one line naming it, nothing written."""
    out = tmp_path / "est.json"
    assert main(["localize", str(write(tmp_path, good_doc)), "-o", str(out), *argv]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert f"{option}: " in line and "appl" in line, line
    assert not out.exists()


def test_the_log_writer_never_writes_what_the_reader_refuses():
    """An in-memory log with odometry on its first step is written without it, so it reads back."""
    import dataclasses

    from decentral.observations import Odometry
    from sims.io.log_json import parse_log

    log = parse_log(CONTRACT_EXAMPLE)
    first = dataclasses.replace(log.steps[0], odometry={"A1": Odometry(np.array([0.01, 0.0, 0.0]), 0.0)})
    doc = log_to_dict(dataclasses.replace(log, steps=(first, *log.steps[1:])))
    assert "odometry" not in doc["steps"][0] and doc["steps"][1]["odometry"]
    assert parse_log(doc).steps[0].odometry == {}
