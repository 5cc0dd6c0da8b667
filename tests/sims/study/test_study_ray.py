"""The Ray engine gives the same rows as the local pool (one Ray instance for the module, 2 CPUs)."""

from __future__ import annotations

import pytest

from sims.study.engines import LocalEngine, RayEngine
from sims.study.runner import run_study
from sims.study.spec import parse_spec

ray = pytest.importorskip("ray")  # in the test extras; a plain install without it skips

#: columns that may differ between engines: timing, memory and where/when a cell ran
NOT_COMPARED = ("id", "seconds", "cpu_seconds", "solve_cpu_seconds", "peak_mb", "engine", "host", "pid", "node", "address", "started",
                "finished", "invocation")


@pytest.fixture(scope="module")
def ray_instance():
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, logging_level="ERROR")
    yield
    ray.shutdown()


def _comparable(db) -> list[tuple]:
    import sqlite3

    with sqlite3.connect(db) as con:
        cols = [r[1] for r in con.execute("PRAGMA table_info(runs)") if r[1] not in NOT_COMPARED]
        return con.execute(f"SELECT {', '.join(cols)} FROM runs ORDER BY cell_key").fetchall()


def test_ray_and_local_pool_give_identical_rows(ray_instance, specs, tmp_path):
    """Same spec on both engines: every parameter, status, error and metric equal (timing excluded)."""
    text = specs["localize"] + "\n"
    local = run_study(parse_spec(text), tmp_path / "local", LocalEngine(2))
    remote = run_study(parse_spec(text), tmp_path / "ray", RayEngine())
    assert (local.ran, remote.ran, remote.failed) == (4, 4, 2)
    assert _comparable(tmp_path / "local" / "study.sqlite") == _comparable(tmp_path / "ray" / "study.sqlite")


def test_ray_engine_resumes_a_store_begun_locally(ray_instance, specs, tmp_path, rows):
    """Cells done on the local pool are not run again on Ray; the rest are, each once."""
    spec = parse_spec(specs["ensemble"])
    run_study(parse_spec(specs["ensemble"].replace("n = [60, 120]", "n = [60]")), tmp_path, LocalEngine(1))
    result = run_study(spec, tmp_path, RayEngine())
    assert (result.skipped, result.ran) == (2, 2)
    engines = sorted(r[0] for r in rows(tmp_path / "study.sqlite", "engine"))
    assert engines == ["local", "local", "ray", "ray"]
