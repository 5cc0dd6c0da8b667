"""Usage mistakes end with one stderr line that says how to fix them, and exit status 2.

Each kind of mistake is run as a user would make it, in a subprocess of the ``decentral`` entry point.
"""

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from sims.cli.main import COMMANDS, GROUPS

ROOT = Path(__file__).resolve().parents[2]


def decentral(*argv, cwd=None) -> tuple[int, str]:
    """Exit status and stderr of ``decentral ARGV`` in a fresh interpreter."""
    proc = subprocess.run([sys.executable, "-m", "sims.cli.main", *map(str, argv)], capture_output=True, text=True,
                          cwd=cwd, timeout=300)
    return proc.returncode, proc.stderr


def one_line(status: int, err: str) -> str:
    """The single stderr line of a refused command (asserting exit 2 and no traceback)."""
    assert status == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """One file of each kind a user might hand to the wrong command."""
    root = tmp_path_factory.mktemp("kinds")
    png = root / "frame.png"
    png.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(64))
    np.savez(root / "obs.npz", format=np.array("decentral.ensemble/1"), dim=np.array(2), n=np.array(2),
             radius=np.array(0.05), i=np.array([0, 1]), j=np.array([1, 0]), z=np.zeros((2, 2)))
    (root / "est.json").write_text(json.dumps({"format": "decentral.estimate/1", "reference": "A0", "steps": []}))
    (root / "dets.json").write_text(json.dumps({"format": "decentral.detections/1", "frames": []}))
    (root / "spec.toml").write_text('name = "t"\ncommand = "localize"\n[fixed]\nscenario = "multi"\n'
                                    'n_assembly = 3\n[grid]\nseed = [1]\n')
    return root


@pytest.mark.parametrize("given,command,says", [
    ("frame.png", "localize", "frame.png: this is an image, not an observation log (decentral.log/1); "
                              "`decentral perceive` reads images"),
    ("obs.npz", "localize", "obs.npz: format: this is ensemble observations (decentral.ensemble/1), not an "
                            "observation log (decentral.log/1); use `decentral ensemble`"),
    ("est.json", "localize", "est.json: format: this is an estimate (decentral.estimate/1), not an observation "
                             "log (decentral.log/1); `decentral score EST TRUTH` and `decentral export` read"),
    ("dets.json", "localize", "dets.json: format: this is a detections file (decentral.detections/1), not an "
                              "observation log (decentral.log/1); `decentral build-log` reads it"),
    ("est.json", "ensemble", "est.json: format: this is an estimate (decentral.estimate/1), not ensemble "
                             "observations (decentral.ensemble/1)"),
])
def test_a_file_of_another_kind_says_what_it_is_and_which_command_reads_it(files, given, command, says):
    """The line names the file, what it is, what the command expected, and the command that reads it."""
    line = one_line(*decentral(command, given, "-o", "out.x", cwd=files))
    assert line.startswith(f"decentral {command}: error: ") and says in line, line
    assert not (files / "out.x").exists()


def test_a_file_given_for_a_folder_says_what_it_is(files):
    """`decentral report spec.toml` says the file is a study specification, which `decentral study` reads."""
    line = one_line(*decentral("report", "spec.toml", cwd=files))
    assert line == ("decentral report: error: spec.toml: this is a study specification (TOML with [grid]), not a "
                    "folder holding study.sqlite; `decentral study` reads it"), line


def test_an_unknown_option_names_the_command_help_and_the_closest_option(files):
    """`localize --windw 5` suggests --window and points at `decentral localize --help`."""
    line = one_line(*decentral("localize", "log.json", "-o", "e.json", "--windw", "5", cwd=files))
    assert "unrecognized option --windw (did you mean --window?)" in line, line
    assert line.endswith("(see decentral localize --help)"), line


def test_an_abbreviated_option_is_refused_not_guessed(files):
    """`--wind 3` is not taken as --window: it is refused, with --window suggested."""
    line = one_line(*decentral("localize", "log.json", "-o", "e.json", "--wind", "3", cwd=files))
    assert "unrecognized option --wind (did you mean --window?)" in line, line


def test_a_misspelt_required_option_is_named_beside_the_missing_one(files):
    """`keys A0 --out DIR` says -o/--output is required and that --out is unknown (did you mean --output?)."""
    line = one_line(*decentral("keys", "A0", "--out", "k", cwd=files))
    assert "required: -o/--output; unrecognized option --out (did you mean --output?)" in line, line
    assert not (files / "k").exists()


def test_a_misspelt_command_or_choice_suggests_the_closest(files):
    """`decentral localise` suggests localize; `--mode admn` suggests admm, naming localize's --help."""
    line = one_line(*decentral("localise", "x", cwd=files))
    assert "invalid choice: 'localise'" in line and "(did you mean localize?)" in line, line
    line = one_line(*decentral("localize", "log.json", "-o", "e.json", "--mode", "admn", cwd=files))
    assert "(did you mean admm?)" in line and line.endswith("(see decentral localize --help)"), line


def test_an_unknown_study_key_suggests_the_closest_and_lists_the_known(files):
    """A spec typo (`n_assembly`) names the key, suggests n_assemblies and lists the valid keys."""
    line = one_line(*decentral("study", "spec.toml", "-o", "study", cwd=files))
    assert "spec.toml: [fixed] n_assembly: unknown key" in line, line
    assert "did you mean n_assemblies?" in line and "known: " in line and "window" in line, line


def test_an_unknown_set_key_suggests_the_closest_and_lists_the_known(files):
    """`simulate --set n_assembly=3` suggests n_assemblies and lists the scenario's parameters."""
    line = one_line(*decentral("simulate", "multi", "-o", "sim", "--set", "n_assembly=3", cwd=files))
    assert "unknown parameter(s) n_assembly" in line and "did you mean n_assemblies?" in line, line
    assert "known: " in line and "steps" in line, line


def test_top_level_help_groups_every_command_by_workflow_with_an_example():
    """`decentral --help` lists each registered command once, under a workflow heading with an example."""
    out = subprocess.run([sys.executable, "-m", "sims.cli.main", "--help"], capture_output=True, text=True,
                         check=True, env={**os.environ, "COLUMNS": "200"}).stdout
    for title in GROUPS:
        section = out.split(f"\n{title}:\n", 1)[1].split("\n\n", 1)[0]
        assert "  e.g. decentral " in section, title
    listed = re.findall(r"^  ([a-z][a-z-]*)  ", out.split("\noptions:", 1)[0], re.MULTILINE)
    assert sorted(listed) == sorted(COMMANDS)
