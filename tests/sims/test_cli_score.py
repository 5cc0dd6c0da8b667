"""``decentral score`` on a decentral.estimate/1: times that match no truth step are said so, not scored as gaps."""

import json

import pytest

from decentral.estimator import EstimatorConfig, estimate_log
from sims.cli.main import main
from sims.io.log_json import estimate_to_dict
from sims.simulation.scenarios import get_scenario, simulate
from sims.simulation.scenarios.output import save_simulation


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A simulated 2-assembly run: its folder and its estimate as a JSON document."""
    root = tmp_path_factory.mktemp("score")
    sim = simulate(get_scenario("multi", n_assemblies=2, steps=6), seed=2)
    save_simulation(sim, root)
    return root, estimate_to_dict(estimate_log(sim.log, EstimatorConfig(window=3)))


def write_shifted(root, doc, shift, count):
    """The estimate with the times of its first ``count`` steps moved by ``shift`` seconds."""
    doc = json.loads(json.dumps(doc))
    for step in doc["steps"][:count]:
        step["t"] += shift
    path = root / f"est_{count}.json"
    path.write_text(json.dumps(doc))
    return path


def test_an_estimate_of_another_time_base_is_refused_naming_the_times(run, capsys):
    """No estimate time is a truth time: exit 2, one line naming the estimate and both first times."""
    root, doc = run
    est = write_shifted(root, doc, 100.0, len(doc["steps"]))
    assert main(["score", str(est), str(root / "truth.json")]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert f"{est}: steps[0].t: no estimate step time matches a truth time" in line, line
    assert f"first estimate t={doc['steps'][0]['t'] + 100:g}" in line


def test_unmatched_steps_are_warned_about_and_the_rest_scored(run, capsys):
    """Some estimate times match no truth time: a warning counts them, the others are scored (exit 0)."""
    root, doc = run
    est = write_shifted(root, doc, 0.01, 2)
    assert main(["-q", "score", str(est), str(root / "truth.json")]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"decentral score: warning: 2 of {len(doc['steps'])} estimate steps match no truth time "
                   "and are not scored"]


def test_every_column_of_the_score_table_is_explained_in_help_and_docs(run, capsys):
    """Each column the decentral.estimate/1 table prints has a line in `score --help` (COLUMNS) and in docs/cli.md."""
    import re
    from pathlib import Path

    from sims.cli.score import COLUMNS

    root, doc = run
    est = root / "est_all.json"
    est.write_text(json.dumps(doc))
    assert main(["score", str(est), str(root / "truth.json")]) == 0
    header = capsys.readouterr().out.splitlines()[0]
    columns = re.split(r"\s{2,}", header.strip())[1:]  # the first column names the rows
    section = COLUMNS.split("columns of an ensemble score", 1)[0]
    docs = (Path(__file__).resolve().parents[2] / "docs" / "cli.md").read_text(encoding="utf-8")
    for name in columns:
        assert f"\n  {name}  " in section, name
        assert f"| `{name}` |" in docs, name
