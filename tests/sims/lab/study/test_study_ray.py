"""The Ray engine gives the same rows as the local pool (one Ray instance for the module, 2 CPUs)."""

from __future__ import annotations

import pytest

from sims.lab.study.engines import LocalEngine, RayEngine
from sims.lab.study.runner import run_study
from sims.lab.study.spec import parse_spec

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


class _FilesGoneEngine(RayEngine):
    """Deletes the study's input files after the driver read them, before any cell runs."""

    def __init__(self, files):
        super().__init__()
        self.files = files

    def run(self, cells, on_result):
        for f in self.files:
            f.unlink()
        super().run(cells, on_result)


def test_recorded_logs_reach_ray_workers_without_the_files(ray_instance, tmp_path):
    """Log cells run on Ray from the texts shipped through the object store, the files gone from disk meanwhile."""
    from sims.io.log_json import write_log
    from sims.simulation.scenarios import get_scenario, simulate
    from sims.lab.study.spec import read_spec
    from sims.simulation.world.truth import write_truth

    files = []
    for seed in (1, 2):
        sim = simulate(get_scenario("multi", n_assemblies=2, steps=3), seed=seed)
        (tmp_path / f"r{seed}").mkdir()
        write_log(tmp_path / f"r{seed}" / "log.json", sim.log)
        write_truth(tmp_path / f"r{seed}" / "truth.json", sim.truth)
        files += [tmp_path / f"r{seed}" / "log.json", tmp_path / f"r{seed}" / "truth.json"]
    (tmp_path / "spec.toml").write_text('name = "logs"\ncommand = "localize"\n[fixed]\ntruth = "beside"\n'
                                        '[grid]\nlog = ["r1/log.json", "r2/log.json"]\n')
    result = run_study(read_spec(tmp_path / "spec.toml"), tmp_path / "out", _FilesGoneEngine(files))
    assert (result.ran, result.failed) == (2, 0) and not any(f.exists() for f in files)


def test_a_task_failing_in_ray_leaves_one_line_with_its_cause_and_where(ray_instance, specs, tmp_path, monkeypatch):
    """A worker that cannot run the cell (here: the package missing) gives a failed row: cause, address, pid."""
    import sqlite3

    import sims.lab.study.engines as engines

    def missing_package(command, params, key, texts=None):
        raise ModuleNotFoundError("No module named 'sims'")

    monkeypatch.setattr(engines, "work", missing_package)
    result = run_study(parse_spec(specs["ensemble"]), tmp_path, RayEngine())
    assert (result.ran, result.failed) == (4, 4)
    with sqlite3.connect(tmp_path / "study.sqlite") as con:
        rows = con.execute("SELECT error, address, pid FROM runs").fetchall()
    for error, address, pid in rows:
        assert error == "Ray task failed: ModuleNotFoundError: No module named 'sims'"
        assert address and pid


def test_ray_rows_record_the_node_id_and_address(ray_instance, specs, tmp_path):
    """Each Ray row names its raylet (node id, hex) and the node's IP address, not only a hostname."""
    import sqlite3

    run_study(parse_spec(specs["ensemble"].replace("n = [60, 120]", "n = [60]")), tmp_path, RayEngine())
    with sqlite3.connect(tmp_path / "study.sqlite") as con:
        rows = con.execute("SELECT node, address FROM runs").fetchall()
    node_id = ray.get_runtime_context().get_node_id()
    node_address = next(n["NodeManagerAddress"] for n in ray.nodes() if n["NodeID"] == node_id)
    assert rows and all(node == node_id and address == node_address for node, address in rows)
