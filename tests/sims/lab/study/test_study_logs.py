"""Studies over recorded logs: the `log` and `truth` keys, read and validated before any cell runs."""

from __future__ import annotations

import json
import sqlite3

import pytest

from decentral.errors import InputError
from sims.io.log_json import write_log
from sims.simulation.scenarios import get_scenario, simulate
from sims.lab.study.cells import check_cells
from sims.lab.study.engines import LocalEngine
from sims.lab.study.runner import run_study
from sims.lab.study.spec import parse_spec, read_spec
from sims.simulation.world.truth import write_truth

SCENARIO = {"n_assemblies": 2, "steps": 4}


def _record(folder, seed: int) -> None:
    """What `decentral simulate multi -o FOLDER` writes: log.json and truth.json."""
    sim = simulate(get_scenario("multi", **SCENARIO), seed=seed)
    folder.mkdir(parents=True, exist_ok=True)
    write_log(folder / "log.json", sim.log)
    write_truth(folder / "truth.json", sim.truth)


def _spec(tmp_path, body: str):
    path = tmp_path / "spec.toml"
    path.write_text(f'name = "recorded"\ncommand = "localize"\n{body}')
    return read_spec(path)


def _runs(directory, columns: str) -> list[tuple]:
    with sqlite3.connect(directory / "study.sqlite") as con:
        return con.execute(f"SELECT {columns} FROM runs ORDER BY cell_key").fetchall()


METRICS = "status, pos_error_m, rel_error_pct, angle_error_deg, coverage, certified"


def test_a_recorded_log_and_its_truth_score_as_the_simulated_cell(tmp_path):
    """Localizing the recorded log of a simulation gives that simulated cell's metrics exactly."""
    _record(tmp_path / "run", seed=3)
    recorded = _spec(tmp_path, '[fixed]\nlog = "run/log.json"\ntruth = "run/truth.json"\n')
    simulated = parse_spec('name = "sim"\ncommand = "localize"\n[fixed]\nscenario = "multi"\nn_assemblies = 2\n'
                           'steps = 4\nseed = 3\n')
    run_study(recorded, tmp_path / "a", LocalEngine(1))
    run_study(simulated, tmp_path / "b", LocalEngine(1))
    a, b = _runs(tmp_path / "a", METRICS), _runs(tmp_path / "b", METRICS)
    assert a == b and a[0][0] == "ok" and a[0][1] is not None


def test_logs_as_a_grid_axis_with_the_truth_beside_each(tmp_path):
    """log = [...] in [grid] with truth = "beside": one scored row per log, paths relative to the spec."""
    _record(tmp_path / "a", seed=1)
    _record(tmp_path / "b", seed=2)
    spec = _spec(tmp_path, '[fixed]\ntruth = "beside"\n[grid]\nlog = ["a/log.json", "b/log.json"]\n')
    result = run_study(spec, tmp_path / "out", LocalEngine(2))
    got = _runs(tmp_path / "out", "log, truth, status, pos_error_m")
    assert result.ran == 2 and [g[:3] for g in got] == [("a/log.json", "beside", "ok"), ("b/log.json", "beside", "ok")]
    assert got[0][3] != got[1][3]  # two different recordings


def test_without_truth_a_row_holds_what_needs_no_truth(tmp_path):
    """No truth: errors are NULL; coverage (from the estimate) and the localization's own figures are kept."""
    _record(tmp_path / "run", seed=1)
    spec = _spec(tmp_path, '[fixed]\nlog = "run/log.json"\n')
    run_study(spec, tmp_path / "out", LocalEngine(1))
    status, pos, rel, yaw, coverage, certified = _runs(tmp_path / "out", METRICS)[0]
    assert status == "ok" and (pos, rel, yaw) == (None, None, None)
    assert coverage == 1.0 and certified is not None


def test_a_changed_log_file_is_a_new_cell(tmp_path):
    """The cell's identity includes its files' contents: a re-recorded log runs again, an unchanged one does not."""
    _record(tmp_path / "run", seed=1)
    spec = _spec(tmp_path, '[fixed]\nlog = "run/log.json"\n')
    assert run_study(spec, tmp_path / "out", LocalEngine(1)).ran == 1
    assert run_study(spec, tmp_path / "out", LocalEngine(1)).ran == 0
    _record(tmp_path / "run", seed=2)
    assert run_study(spec, tmp_path / "out", LocalEngine(1)).ran == 1


def test_a_bad_log_is_refused_before_any_cell_naming_the_file_and_field(tmp_path):
    """A log whose step time is text: InputError naming the log file and steps[1].t; no store is made."""
    _record(tmp_path / "run", seed=1)
    doc = json.loads((tmp_path / "run" / "log.json").read_text())
    doc["steps"][1]["t"] = "soon"
    (tmp_path / "run" / "log.json").write_text(json.dumps(doc))
    spec = _spec(tmp_path, '[grid]\nlog = ["run/log.json"]\n')
    with pytest.raises(InputError) as err:
        run_study(spec, tmp_path / "out", LocalEngine(1))
    assert err.value.source.endswith("run/log.json") and "steps[1].t" in err.value.field
    assert not (tmp_path / "out").exists()


def test_a_missing_log_names_the_file_and_the_key(tmp_path):
    """A log that does not exist: the error names the path and says the study's log key named it."""
    with pytest.raises(InputError, match="file not found.*log key") as err:
        check_cells(_spec(tmp_path, '[fixed]\nlog = "nowhere.json"\n'))
    assert err.value.source.endswith("nowhere.json")


def test_a_truth_of_another_run_is_refused(tmp_path):
    """A truth without the log's assemblies (another run's) is refused naming the truth file."""
    _record(tmp_path / "run", seed=1)
    doc = json.loads((tmp_path / "run" / "truth.json").read_text())
    for step in doc["steps"]:
        step["poses"] = {f"X{i}": pose for i, pose in enumerate(step["poses"].values())}
    doc["reference"] = "X0"
    (tmp_path / "other.json").write_text(json.dumps(doc))
    with pytest.raises(InputError, match="no poses of") as err:
        check_cells(_spec(tmp_path, '[fixed]\nlog = "run/log.json"\ntruth = "other.json"\n'))
    assert err.value.source.endswith("other.json")


@pytest.mark.parametrize("body, field", [
    ('[fixed]\nlog = "run/log.json"\nscenario = "multi"\n', "scenario"),
    ('[fixed]\nlog = "run/log.json"\nn_assemblies = 3\n', "n_assemblies"),
    ('[fixed]\nscenario = "multi"\ntruth = "run/truth.json"\n', "truth"),
])
def test_keys_that_do_not_apply_to_a_recorded_log_are_refused(tmp_path, body, field):
    """Scenario keys beside a log, or a truth without a log, end the study naming the key."""
    _record(tmp_path / "run", seed=1)
    with pytest.raises(InputError) as err:
        check_cells(_spec(tmp_path, body))
    assert err.value.field == f"[fixed] {field}"


def test_the_cli_refuses_a_bad_log_in_one_line_with_exit_2(tmp_path, cli):
    """`decentral study` over a log that is not JSON: exit 2, one stderr line naming the file, no traceback."""
    (tmp_path / "log.json").write_text("{ not json")
    spec = tmp_path / "spec.toml"
    spec.write_text('name = "bad"\ncommand = "localize"\n[fixed]\nlog = "log.json"\n')
    proc = cli("study", str(spec), "-o", str(tmp_path / "out"))
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1 and "log.json" in lines[0] and "JSON" in lines[0]
    assert "Traceback" not in proc.stderr
