"""The README works as written: its walk-through and Python example run, its example log places its
target, its quick start is two commands, and it speaks to a user (no paths outside the repository)."""

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from sims.cli.main import COMMANDS, build_parser, main

ROOT = Path(__file__).resolve().parent.parent
README = (ROOT / "README.md").read_text(encoding="utf-8")


def block_after(heading: str, lang: str) -> str:
    """The first ```lang code block after ``heading`` in the README."""
    start = README.index(heading)
    match = re.compile(rf"```{lang}\n(.*?)```", re.S).search(README, start)
    return match.group(1)


def venv_link(tmp_path: Path) -> None:
    """Make ``tmp_path/.venv`` the environment running the tests, as on a fresh clone after the quick start."""
    (tmp_path / ".venv").symlink_to(Path(sys.prefix), target_is_directory=True)


def test_walkthrough_runs_as_written(tmp_path):
    """Every command of "From your robots' data to an evo plot" succeeds and leaves its evo plots."""
    venv_link(tmp_path)
    script = block_after("## From your robots' data to an evo plot", "bash")
    env = {**os.environ, "HOME": str(tmp_path), "MPLBACKEND": "Agg"}
    done = subprocess.run(["bash", "-e", "-c", script], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    assert "not aligned" in done.stdout
    plots = sorted(p.name for p in (tmp_path / "out" / "walk").glob("*.png"))
    assert any(p.startswith("ape_A1") for p in plots) and any(p.startswith("trajectories") for p in plots)
    rig = (tmp_path / "out" / "walk" / "robots" / "rig.toml").read_text()
    shown = block_after("is what you would write for your own robots", "toml")
    for line in shown.splitlines():  # the excerpt's keys are the generated file's
        key = line.split("=")[0].strip()
        if line.strip() and not line.startswith("#") and "=" in line:
            assert re.search(rf"^{re.escape(key)} = ", rig, re.M), key


def test_python_example_runs_and_places_the_target(tmp_path):
    """The Python API example runs as a script and places A1 at both steps in both modes."""
    code = block_after("## Python API", "python")
    (tmp_path / "example.py").write_text(code)
    done = subprocess.run([sys.executable, "example.py"], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert len([line for line in lines if line.startswith("t=") and "not placed: {}" in line]) == 2
    assert (tmp_path / "log.json").exists() and (tmp_path / "estimate.json").exists()


def test_example_log_places_its_target(tmp_path, capsys):
    """The decentral.log/1 example of the README localizes with A1 placed at every step."""
    doc = json.loads(block_after("### `decentral.log/1` (JSON)", "json"))
    (tmp_path / "log.json").write_text(json.dumps(doc))
    assert main(["localize", str(tmp_path / "log.json"), "-o", str(tmp_path / "est.json")]) == 0
    steps = json.loads((tmp_path / "est.json").read_text())["steps"]
    assert all("A1" in s["poses"] and not s["unplaced"] for s in steps)
    assert "2 placements" in capsys.readouterr().err


def test_quick_start_is_two_commands():
    """The quick start block holds exactly the install-and-demo command and the test command."""
    lines = [line for line in block_after("## Quick start", "bash").splitlines() if line.strip()]
    assert len(lines) == 2 and lines[1] == "bash .ci/run" and lines[0].endswith(".venv/bin/decentral demo")


def test_readme_points_inside_the_repository_and_speaks_to_users():
    """No path outside the repository, no words about how it was developed, every linked file exists."""
    assert "../" not in README
    for word in ("session", "brief", "issue", "seed 00", "seed's"):
        assert word not in README.lower(), word
    for target in re.findall(r"\]\(([^)#]+)\)|src=\"([^\"]+)\"|!\[[^\]]*\]\(([^)]+)\)", README):
        path = next(t for t in target if t)
        if not path.startswith("http"):
            assert (ROOT / path).exists(), path


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_every_option_of_every_command_has_help(name):
    """Each command's --help documents every argument (no bare option without a description)."""
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command").choices[name]
    for action in sub._actions:
        if action.dest != "help":
            assert action.help and action.help.strip(), f"{name} {action.option_strings or action.dest}"


def test_code_and_docs_cite_the_papers_by_their_authors():
    """No module, test, benchmark or document refers to a paper by an internal number (seed and three
    digits) that a reader of the package cannot resolve, nor to how the project was developed (a
    numbered session or issue)."""
    banned = re.compile(r"\bseeds? 00[0-9]\b|\bsession[- ][0-9]|\bissue [0-9]", re.IGNORECASE)
    offenders = []
    for folder in ("decentral", "protocols", "agents", "sims", "benchmarks", "tests", "docs", "studies"):
        for path in sorted((ROOT / folder).rglob("*")):
            if path.suffix in (".py", ".md", ".toml") and path.is_file():
                for k, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
                    if banned.search(line) and "banned = re.compile" not in line:
                        offenders.append(f"{path.relative_to(ROOT)}:{k}")
    assert not offenders, offenders[:10]
