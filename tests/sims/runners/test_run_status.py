"""``stats.status``: ``ok`` exactly when every step converged; otherwise ``degraded``, one warning line, and
exit 4 under ``--strict``."""

import json

import pytest

from sims.cli.main import main
from sims.runners.run_status import EXIT_DEGRADED, run_status, status_warning


@pytest.fixture(scope="module")
def sim6(tmp_path_factory):
    """A 6-step, 5-assembly multi log."""
    out = tmp_path_factory.mktemp("sim6")
    assert main(["-q", "simulate", "multi", "-o", str(out), "--steps", "6", "--set", "n_assemblies=5"]) == 0
    return out


def _warnings(err, command):
    return [ln for ln in err.splitlines() if ln.startswith(f"decentral {command}: warning: ")]


def test_status_is_ok_only_when_every_step_converged():
    """One unconverged step, or one step never run, makes the run degraded; counts say which."""
    assert run_status([True] * 3, [True] * 3)[0] == "ok"
    status, counts = run_status([True, False, False], [True, True, False], {"no_consensus": 3})
    assert status == "degraded"
    assert counts["unconverged"] == 2 and counts["provisional"] == 1 and counts["unanswered"] == 1
    assert counts["no_consensus"] == 3
    assert run_status([True], [True], not_run=1)[0] == "degraded"
    assert run_status([True], [True], timed_out=True)[0] == "timeout"


def test_warning_line_is_one_line_naming_the_counts():
    """The warning of a degraded run is one line naming how many steps were provisional and unplaced."""
    status, counts = run_status([False, False, True], [True, False, True], {"no_consensus": 4})
    line = status_warning(status, counts, 3)
    assert "\n" not in line and "2 of 3 steps did not converge" in line and "1 provisional" in line
    assert "no_consensus 4" in line
    assert status_warning("ok", run_status([True], [True])[1], 1) is None


def test_admm_run_that_cannot_converge_is_degraded_warns_and_fails_strict(sim6, tmp_path, capsys):
    """--max-rounds 1: no window can converge, not even in the background (2 rounds); status degraded, one warning
    line, exit 4 with --strict only."""
    out = tmp_path / "e.json"
    argv = ["localize", str(sim6 / "log.json"), "-o", str(out), "--mode", "admm", "--max-rounds", "1"]
    assert main(argv) == 0
    err = capsys.readouterr().err
    stats = json.loads(out.read_text())["stats"]
    assert stats["status"] == "degraded" and stats["status_counts"]["unconverged"] == 6
    [line] = _warnings(err, "localize")
    assert "6 of 6 steps did not converge" in line and "6 provisional" in line
    assert main(argv + ["--strict"]) == EXIT_DEGRADED == 4


def test_admm_run_that_converges_is_ok_and_silent(sim6, tmp_path, capsys):
    """A run whose every step converged says ok, warns nothing and exits 0 under --strict."""
    out = tmp_path / "e.json"
    assert main(["localize", str(sim6 / "log.json"), "-o", str(out), "--mode", "admm", "--strict"]) == 0
    stats = json.loads(out.read_text())["stats"]
    assert stats["all_converged"] and stats["status"] == "ok"
    assert not _warnings(capsys.readouterr().err, "localize")


def test_strict_only_applies_to_admm(sim6, tmp_path, capsys):
    """--strict with the centralized estimator (no consensus to fail) is refused, exit 2."""
    assert main(["localize", str(sim6 / "log.json"), "-o", str(tmp_path / "e.json"), "--strict"]) == 2
    assert "--strict" in capsys.readouterr().err


def test_study_row_records_a_degraded_run(tmp_path):
    """A study cell whose consensus does not converge finishes ('ok', with its metrics) and its row's
    run_status says 'degraded'; the store keeps both (its status column stays 'ok' or 'failed')."""
    from sims.lab.study.cells import execute
    from sims.lab.study.store import DB_NAME, open_store, read_runs

    row = execute("localize", {"scenario": "multi", "n_assemblies": 4, "steps": 3, "mode": "admm",
                               "max_rounds": 1}, "k")
    assert row["status"] == "ok" and row["run_status"] == "degraded" and row["error"] is None
    assert row["metrics"]["converged"] == 0 and "_status" not in row["metrics"]
    store = open_store(tmp_path, "s", "localize", ["mode"], ["converged"])
    try:
        assert store.add_run({"mode": "admm"}, row, "local", store.begin_invocation({"engine": "local"}))
    finally:
        store.close()
    (stored,) = read_runs(tmp_path / DB_NAME)[1]
    assert stored["status"] == "ok" and stored["run_status"] == "degraded" and stored["converged"] == 0


def test_simulated_latency_beyond_the_round_budget_degrades_the_run(sim6, tmp_path):
    """200 ms links with 8 rounds of 25 ms per step (what processes at that pace get): no window converges before
    its next step; those that converge in the background are counted as revised, the others make it degraded."""
    out = tmp_path / "e.json"
    assert main(["-q", "localize", str(sim6 / "log.json"), "-o", str(out), "--mode", "admm", "--latency", "0.16",
                 "--jitter", "0.08", "--round-period", "0.025", "--max-rounds", "8"]) == 0
    stats = json.loads(out.read_text())["stats"]
    counts = stats["status_counts"]
    assert counts["unconverged"] + counts["revised"] == 6 and counts["unconverged"] >= 1
    assert stats["status"] == "degraded" and len(stats["revised"]) == counts["revised"] + counts["reanswered"]
    assert counts["reanswered"] == sum(1 for r in stats["revised"] if r["reason"] == "more_forms")
