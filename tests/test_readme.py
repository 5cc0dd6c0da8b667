"""The README and the docs work as written: the walk-through leaves the files it names, the Python
example runs, the example log places its target, the quick start is two commands, and they speak to
a user (no paths outside the repository, no words about how the project was developed, result files
named by their parameters and cited)."""

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
DOCS = ROOT / "docs"
RESULTS = ROOT / "benchmarks" / "results"
#: what a reader reads: the README, the documentation site's pages and the benchmarks' README
PAGES = [ROOT / "README.md", ROOT / "benchmarks" / "README.md", *sorted(DOCS.glob("*.md"))]
#: words about how the project was developed, not about what it does
HISTORY = re.compile(r"\bsessions?\b|\bbrief\b|\bissue #?[0-9]|\bseeds? 00[0-9]\b|contract §|\(contract\b"
                     r"|previous top refinement|met in every run|re-?run after|\bthe lead\b", re.IGNORECASE)
#: parts of a file name that say when or in which attempt it was made, not what it measured
WHEN = re.compile(r"_s[0-9]+(_|$)|rerun|re-run|_first|_final|_old|_new|_latest|_v[0-9]+$|20[0-9]{2}-?[01][0-9]")


def block_after(heading: str, lang: str, text: str = README) -> str:
    """The first ```lang code block after ``heading`` in ``text`` (the README by default)."""
    start = text.index(heading)
    match = re.compile(rf"```{lang}\n(.*?)```", re.S).search(text, start)
    return match.group(1)


def paragraph_after(heading: str, lang: str, text: str = README) -> str:
    """The prose between the first ```lang block after ``heading`` and the next heading."""
    start = text.index(heading)
    end_of_block = re.compile(rf"```{lang}\n.*?```", re.S).search(text, start).end()
    following = text.find("\n#", end_of_block)
    return text[end_of_block:following if following >= 0 else len(text)]


def venv_link(tmp_path: Path) -> None:
    """Make ``tmp_path/.venv`` the environment running the tests, as on a fresh clone after the quick start."""
    (tmp_path / ".venv").symlink_to(Path(sys.prefix), target_is_directory=True)


WALK = "## From your robots' data to an evo plot"


def test_walkthrough_names_the_files_evo_writes_for_its_save_plot_arguments():
    """Every plot path the walk-through names derives from one of its --save_plot arguments as evo names them."""
    script = block_after(WALK, "bash")
    named = set(re.findall(r"`(out/walk/[^`]+\.png)`", paragraph_after(WALK, "bash")))
    stems = {Path(p).with_suffix("").as_posix() for p in re.findall(r"--save_plot (\S+)", script)}
    evo_suffixes = {"evo_ape": ("_raw", "_map"), "evo_traj": ("_trajectories", "_xyz", "_rpy", "_speeds")}
    expected = set()
    for line in script.splitlines():
        tool = next((t for t in evo_suffixes if f"/{t} " in line), None)
        if tool:
            stem = Path(re.search(r"--save_plot (\S+)", line).group(1)).with_suffix("").as_posix()
            expected |= {f"{stem}{s}.png" for s in evo_suffixes[tool]}
    assert len(stems) == 2 and named == expected, (named, expected)


@pytest.mark.slow
def test_walkthrough_runs_as_written_and_leaves_the_files_it_names(tmp_path):
    """The walk-through's commands, run exactly as printed, succeed and write every file its text names, and no other plot."""
    venv_link(tmp_path)
    script = block_after(WALK, "bash")
    env = {**os.environ, "HOME": str(tmp_path), "MPLBACKEND": "Agg"}
    done = subprocess.run(["bash", "-e", "-c", script], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=900)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    assert "not aligned" in done.stdout  # evo_ape compared the two trajectories in the reference's frame
    named = set(re.findall(r"`(out/walk/[^`]+)`", paragraph_after(WALK, "bash")))
    assert named, "the walk-through names no file"
    missing = sorted(p for p in named if not (tmp_path / p).is_file())
    assert not missing, missing
    plots = {p.relative_to(tmp_path).as_posix() for p in (tmp_path / "out" / "walk").glob("*.png")}
    assert plots == {p for p in named if p.endswith(".png")}, plots
    rig = (tmp_path / "out" / "walk" / "robots" / "rig.toml").read_text()
    shown = block_after("## Example: a generated rig", "toml", (DOCS / "rig.md").read_text(encoding="utf-8"))
    for line in shown.splitlines():  # the excerpt's keys are the generated file's
        key = line.split("=")[0].strip()
        if line.strip() and not line.startswith("#") and "=" in line:
            assert re.search(rf"^{re.escape(key)} = ", rig, re.M), key


@pytest.mark.slow
def test_simulate_and_study_workflows_run_as_written(tmp_path):
    """The first block of "Simulate and localize" and the study (its TOML saved under the name its
    commands use) run as printed and leave the estimates, the store and the report."""
    venv_link(tmp_path)
    spec_name = re.search(r"decentral study (\S+\.toml)", block_after("## A study", "bash")).group(1)
    (tmp_path / spec_name).write_text(block_after("## A study", "toml"))
    script = block_after("## Simulate and localize", "bash") + block_after("## A study", "bash")
    env = {**os.environ, "HOME": str(tmp_path), "MPLBACKEND": "Agg"}
    done = subprocess.run(["bash", "-e", "-c", script], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=900)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    assert "overall" in done.stdout  # the score table
    for path in ("out/sim/estimate.json", "out/sim/admm.json", "out/loss/study.sqlite", "out/loss/report.html"):
        assert (tmp_path / path).is_file(), path


def test_python_example_runs_and_places_the_target(tmp_path):
    """The Python API example of docs/python.md runs as a script and places A1 at both steps in both modes."""
    code = block_after("# Python API", "python", (DOCS / "python.md").read_text(encoding="utf-8"))
    (tmp_path / "example.py").write_text(code)
    done = subprocess.run([sys.executable, "example.py"], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert len([line for line in lines if line.startswith("t=") and "not placed: {}" in line]) == 2
    assert (tmp_path / "log.json").exists() and (tmp_path / "estimate.json").exists()


def test_example_log_places_its_target(tmp_path, capsys):
    """The decentral.log/1 example of docs/formats.md localizes with A1 placed at every step."""
    doc = json.loads(block_after("## `decentral.log/1` (JSON)", "json", (DOCS / "formats.md").read_text(encoding="utf-8")))
    (tmp_path / "log.json").write_text(json.dumps(doc))
    assert main(["localize", str(tmp_path / "log.json"), "-o", str(tmp_path / "est.json")]) == 0
    steps = json.loads((tmp_path / "est.json").read_text())["steps"]
    assert all("A1" in s["poses"] and not s["unplaced"] for s in steps)
    assert "2 placements" in capsys.readouterr().err


def test_quick_start_is_two_commands():
    """The quick start block holds exactly the install-and-demo command and the test command."""
    lines = [line for line in block_after("## Quick start", "bash").splitlines() if line.strip()]
    assert len(lines) == 2 and lines[1] == "bash .ci/run" and lines[0].endswith(".venv/bin/decentral demo")


def test_readme_fits_a_short_read():
    """The README is at most 250 lines: details live in docs/."""
    assert len(README.splitlines()) <= 250, len(README.splitlines())


def test_readme_lists_every_command():
    """The README's command list has one row per command of the CLI, and no other."""
    rows = re.findall(r"^\| `([a-z-]+)[ `]", README[README.index("## Commands"):], re.M)
    assert sorted(rows) == sorted(COMMANDS), rows


def test_readme_points_inside_the_repository_and_speaks_to_users():
    """No path outside the repository, no words about how it was developed, every linked file exists."""
    assert "../" not in README
    for target in re.findall(r"\]\(([^)#]+)\)|src=\"([^\"]+)\"|!\[[^\]]*\]\(([^)]+)\)", README):
        path = next(t for t in target if t)
        if not path.startswith("http"):
            assert (ROOT / path).exists(), path


def test_pages_say_nothing_about_how_the_project_was_developed():
    """The README, the docs pages and the benchmarks' README use no project-history words."""
    offenders = [f"{page.relative_to(ROOT)}:{k}: {line.strip()[:80]}"
                 for page in PAGES
                 for k, line in enumerate(page.read_text(encoding="utf-8").splitlines(), 1) if HISTORY.search(line)]
    assert not offenders, offenders[:10]


def test_result_files_are_named_by_their_parameters_and_cited():
    """No committed result or study file is named after when or in which attempt it was made, and every
    result file is cited by name in the benchmarks' README or the docs."""
    files = [p for folder in (RESULTS, ROOT / "studies", DOCS) for p in sorted(folder.rglob("*")) if p.is_file()]
    assert files
    badly_named = [p.relative_to(ROOT).as_posix() for p in files if WHEN.search(p.stem)]
    assert not badly_named, badly_named
    cited = "\n".join(page.read_text(encoding="utf-8") for page in PAGES)
    uncited = []
    for path in (p for p in files if p.is_relative_to(RESULTS)):
        stem = path.relative_to(RESULTS).with_suffix("").as_posix()
        if not re.search(rf"(?<![\w.-]){re.escape(stem)}(\.|\b)", cited):
            uncited.append(stem)
    assert not uncited, uncited


def test_every_result_file_a_page_names_exists():
    """Each `benchmarks/results/...` path the pages name (braces and * expanded) matches a committed file."""
    missing = []
    for page in PAGES:
        for path in re.findall(r"benchmarks/results/([\w./*{},-]+)", page.read_text(encoding="utf-8")):
            path = path.rstrip(".,")
            braces = re.search(r"\{([^}]*)\}", path)
            options = [path.replace(braces.group(0), o) for o in braces.group(1).split(",")] if braces else [path]
            missing += [f"{page.name}: {o}" for o in options if o and not list(RESULTS.glob(o))]
    assert not missing, missing


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
    numbered session or issue, or sections of an internal contract)."""
    banned = re.compile(r"\bseeds? 00[0-9]\b|\bsession[- ][0-9]|\bissue [0-9]|contract §|CONTRACT\.md", re.IGNORECASE)
    offenders = []
    for folder in ("decentral", "protocols", "agents", "sims", "benchmarks", "tests", "docs", "studies"):
        for path in sorted((ROOT / folder).rglob("*")):
            if path.suffix in (".py", ".md", ".toml") and path.is_file():
                for k, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
                    if banned.search(line) and "re.compile(" not in line:  # the patterns themselves
                        offenders.append(f"{path.relative_to(ROOT)}:{k}")
    assert not offenders, offenders[:10]
