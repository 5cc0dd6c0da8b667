"""Running studies: one row per cell, failures recorded, resume after SIGKILL, feedback kept out of files."""

from __future__ import annotations

import os
import random
import signal
import sqlite3
import subprocess
import sys
import time

from sims.lab.study.cells import check_cells
from sims.lab.study.engines import LocalEngine, _pinned_environment
from sims.lab.study.runner import run_study
from sims.lab.study.spec import parse_spec
from sims.lab.study.worker import PINNED_ENV


def test_failing_cell_gets_a_failed_row_and_the_others_finish(specs, tmp_path, rows):
    """Cells whose reference does not exist fail with the reason; the other cells of the grid are ok."""
    result = run_study(parse_spec(specs["localize"]), tmp_path, LocalEngine(2))
    assert (result.total, result.ran, result.failed) == (4, 4, 2)
    got = rows(tmp_path / "study.sqlite", "reference, status, error, pos_error_m, messages")
    for reference, status, error, pos_error, messages in got:
        if reference == "nobody":
            assert status == "failed" and "nobody" in error and pos_error is None
        else:
            assert status == "ok" and error is None and pos_error < 0.5 and messages > 0


def test_rerun_runs_only_missing_cells_and_retry_failed_reruns_failures(specs, tmp_path, rows):
    """A second run finds every cell done; --retry-failed runs the failed ones again, with no duplicate."""
    spec = parse_spec(specs["localize"])
    run_study(spec, tmp_path, LocalEngine(2))
    again = run_study(spec, tmp_path, LocalEngine(2))
    assert (again.skipped, again.ran) == (4, 0)
    retried = run_study(spec, tmp_path, LocalEngine(2), retry_failed=True)
    assert (retried.skipped, retried.ran, retried.failed) == (2, 2, 2)
    assert len(rows(tmp_path / "study.sqlite", "cell_key")) == 4


def test_grown_grid_runs_only_the_new_cells(specs, tmp_path, rows):
    """Adding a value to the grid runs just the cells it adds; the stored rows stay as they were."""
    small = specs["ensemble"].replace("n = [60, 120]", "n = [60]")
    run_study(parse_spec(small), tmp_path, LocalEngine(2))
    before = rows(tmp_path / "study.sqlite")
    grown = run_study(parse_spec(specs["ensemble"]), tmp_path, LocalEngine(2))
    assert (grown.skipped, grown.ran) == (2, 2)
    after = rows(tmp_path / "study.sqlite")
    assert set(before) <= set(after) and len(after) == 4


def test_workers_start_with_one_blas_thread_and_the_parent_environment_is_restored(monkeypatch):
    """The pool's processes see OPENBLAS/OMP/MKL_NUM_THREADS=1; the caller's settings come back afterwards."""
    monkeypatch.setenv("OMP_NUM_THREADS", "4")
    engine = LocalEngine(1)
    with _pinned_environment(), engine._pool_of(1) as pool:
        seen = dict(zip(PINNED_ENV, pool.map(os.getenv, PINNED_ENV)))
    assert seen == PINNED_ENV
    assert os.environ["OMP_NUM_THREADS"] == "4"


def test_sigkill_at_random_moments_resumes_to_exactly_the_grid(specs, write_spec, tmp_path, rows):
    """SIGKILL of the whole process group, several times, then a resume: every cell once, no duplicate."""
    text = specs["ensemble"].replace("n = [60, 120]", "n = [40, 60, 80, 100]").replace("seed = [1, 2]",
                                                                                        "seed = [1, 2, 3]")
    spec_path, out = write_spec(text), tmp_path / "out"
    rng = random.Random(12)
    command = [sys.executable, "-m", "sims.cli.main", "-q", "study", str(spec_path), "-o", str(out), "--workers", "2"]
    counts = []
    for _ in range(4):
        proc = subprocess.Popen(command, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        time.sleep(rng.uniform(0.3, 2.5))
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
        counts.append(len(rows(out / "study.sqlite", "cell_key")) if (out / "study.sqlite").exists() else 0)
    done = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    keys = [r[0] for r in rows(out / "study.sqlite", "cell_key")]
    expected = sorted(c.key for c in check_cells(parse_spec(text)))
    assert sorted(keys) == expected  # exactly the grid: nothing lost, nothing twice
    assert counts == sorted(counts)  # a kill never removes a committed row
    with sqlite3.connect(out / "study.sqlite") as con:
        assert con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        assert all(s == "ok" for (s,) in con.execute("SELECT status FROM runs"))


def test_progress_goes_to_stderr_never_into_files_and_q_silences_it(specs, write_spec, tmp_path, cli):
    """With bars forced on, the bar and summary reach stderr only; -q prints nothing at all."""
    spec = write_spec(specs["ensemble"])
    shown = cli("study", str(spec), "-o", str(tmp_path / "a"), "--workers", "2",
                env={"DECENTRAL_PROGRESS": "always"})
    assert shown.returncode == 0, shown.stderr
    assert shown.stdout == ""
    assert "/4 [" in shown.stderr and "cell/s" in shown.stderr and "failed=0" in shown.stderr
    assert "4 cells run (0 failed)" in shown.stderr and " in the grid; wall " in shown.stderr  # wall time, said so
    for path in (tmp_path / "a").iterdir():
        assert b"cell/s" not in path.read_bytes() and b"failed=" not in path.read_bytes()
    quiet = cli("-q", "study", str(spec), "-o", str(tmp_path / "b"), "--workers", "2",
                env={"DECENTRAL_PROGRESS": "always"})
    assert quiet.returncode == 0 and quiet.stdout == "" and quiet.stderr == ""
    report = cli("-q", "report", str(tmp_path / "b"))
    assert report.returncode == 0 and report.stdout == "" and report.stderr == ""


def crash_on_n_99(command, params, key):
    """A worker task that kills its own process for n = 99 and runs every other cell normally."""
    if params["n"] == 99:
        os._exit(1)
    from sims.lab.study.worker import work

    return work(command, params, key)


def test_worker_that_dies_fails_only_its_own_cell(specs, tmp_path, rows):
    """A cell that kills its worker gets a 'failed' row; cells in flight beside it run again and succeed."""
    text = specs["ensemble"].replace("n = [60, 120]", "n = [60, 99, 120]")
    result = run_study(parse_spec(text), tmp_path, LocalEngine(2, task=crash_on_n_99))
    assert (result.total, result.ran, result.failed) == (6, 6, 2)
    for n, status, error in rows(tmp_path / "study.sqlite", "n, status, error"):
        assert (status == "failed") == (n == 99)
        assert n != 99 or "worker process died" in error
