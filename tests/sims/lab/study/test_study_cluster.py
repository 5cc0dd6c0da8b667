"""Running on a cluster: causes of failures in one line, unreachable addresses, ray://, killed runs, placement."""

from __future__ import annotations

import contextlib
import os
import socket
import sqlite3
import subprocess
import sys
import threading

import pytest

from decentral.errors import InputError
from sims.lab.study.engines import LocalEngine, RayEngine, check_reachable, one_line
from sims.lab.study.runner import run_study
from sims.lab.study.spec import parse_spec


class FakeRayTaskError(RuntimeError):
    """Like Ray's: a coloured header and the remote traceback in its text, the original error as ``cause``."""

    def __init__(self, cause: BaseException | None):
        self.cause = cause
        super().__init__("\x1b[36mray::work()\x1b[39m (pid=4242, ip=10.0.0.7)\n  File \"worker.py\", line 3\n"
                         "RuntimeError: The remote function failed to import on the worker.\n"
                         "ModuleNotFoundError: No module named 'sims'")


def test_a_wrapped_remote_error_becomes_its_root_cause_in_one_plain_line():
    """The deepest `SomeError: message` line of the remote traceback, without ANSI colour or newlines."""
    line = one_line(FakeRayTaskError(None))
    assert line == "ModuleNotFoundError: No module named 'sims'"


def test_an_error_without_a_traceback_keeps_its_type_and_last_line():
    """A plain exception reads `Type: message`; a chained cause is preferred to its wrapper."""
    assert one_line(ConnectionError("refused")) == "ConnectionError: refused"
    try:
        try:
            raise OSError("disk full")
        except OSError as inner:
            raise RuntimeError("\x1b[31mwrapper\x1b[0m") from inner
    except RuntimeError as outer:
        assert one_line(outer) == "OSError: disk full"


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.parametrize("scheme", ["", "ray://"])
def test_an_address_nothing_listens_on_is_refused_naming_the_option(scheme):
    """HOST:PORT or ray://HOST:PORT with no listener: InputError on --address saying what to start."""
    with pytest.raises(InputError, match="cannot reach") as err:
        check_reachable(f"{scheme}127.0.0.1:{_closed_port()}", timeout=2)
    assert err.value.field == "--address" and "ray start" in err.value.message


def test_a_malformed_ray_client_address_is_refused():
    """ray:// without HOST:PORT is refused before Ray sees it."""
    with pytest.raises(InputError, match="ray://HOST:PORT"):
        check_reachable("ray://headnode")


@contextlib.contextmanager
def _grpc_like_server():
    """A loopback listener that answers a connection with an HTTP/2 SETTINGS frame, as a gRPC server does."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen()

    def answer():
        conn, _ = server.accept()
        with conn:
            conn.recv(64)
            conn.sendall(b"\x00\x00\x00\x04\x00\x00\x00\x00\x00")

    thread = threading.Thread(target=answer, daemon=True)
    thread.start()
    try:
        yield server.getsockname()[1]
    finally:
        server.close()
        thread.join(timeout=5)


def test_a_ray_client_address_is_passed_to_ray_init_as_given(monkeypatch):
    """--address ray://HOST:PORT reaches ray.init unchanged (Ray Client), with the pinned job environment."""
    ray = pytest.importorskip("ray")
    seen = {}

    def fake_init(**kwargs):
        seen.update(kwargs)
        raise ConnectionError("stop here")

    monkeypatch.setattr(ray, "init", fake_init)
    monkeypatch.setattr(ray, "is_initialized", lambda: False)
    with _grpc_like_server() as port:
        address = f"ray://127.0.0.1:{port}"
        with pytest.raises(InputError, match="ConnectionError: stop here"):
            RayEngine(address).run([], lambda cell, row: None)
    assert seen["address"] == address and seen["runtime_env"]["env_vars"]["OPENBLAS_NUM_THREADS"] == "1"


def test_the_cli_refuses_an_unreachable_cluster_in_one_line_with_exit_2(specs, tmp_path, cli):
    """`decentral study --engine ray --address` with nothing there: exit 2, one stderr line, no stack trace."""
    pytest.importorskip("ray")
    spec = tmp_path / "spec.toml"
    spec.write_text(specs["ensemble"])
    proc = cli("study", str(spec), "-o", str(tmp_path / "out"), "--engine", "ray", "--address",
               f"127.0.0.1:{_closed_port()}")
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1 and "--address" in lines[0] and "cannot reach" in lines[0]


class InlineEngine:
    """Runs cells in this process, one after the other (the runner's bookkeeping without worker start-up)."""

    name = "inline"

    def run(self, cells, on_result) -> None:
        from sims.lab.study.worker import work

        for cell in cells:
            on_result(cell, work(cell.command, dict(cell.params), cell.key))


def _dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def test_a_killed_runs_invocation_is_closed_by_the_next_run(specs, tmp_path):
    """An invocation left 'running' by a vanished driver on this host becomes 'killed' with its row counts."""
    spec = parse_spec(specs["ensemble"])
    run_study(spec, tmp_path, InlineEngine())
    db = tmp_path / "study.sqlite"
    with sqlite3.connect(db) as con:  # as SIGKILL leaves it: status running, no end
        con.execute("UPDATE invocations SET status = 'running', finished = NULL, cells_run = NULL, pid = ?",
                    (_dead_pid(),))
    run_study(spec, tmp_path, InlineEngine())
    with sqlite3.connect(db) as con:
        got = con.execute("SELECT id, status, cells_run, finished IS NOT NULL FROM invocations ORDER BY id").fetchall()
    assert got == [(1, "killed", 4, 1), (2, "finished", 0, 1)]


def test_a_running_invocation_whose_driver_lives_is_left_alone(specs, tmp_path):
    """An invocation whose driver process still exists (this one) keeps its 'running' status."""
    spec = parse_spec(specs["ensemble"])
    run_study(spec, tmp_path, InlineEngine())
    with sqlite3.connect(tmp_path / "study.sqlite") as con:
        con.execute("UPDATE invocations SET status = 'running', pid = ?", (os.getppid(),))
    run_study(spec, tmp_path, InlineEngine())
    with sqlite3.connect(tmp_path / "study.sqlite") as con:
        assert con.execute("SELECT status FROM invocations WHERE id = 1").fetchone() == ("running",)


def test_local_rows_record_host_node_and_pid(specs, tmp_path):
    """On the local pool a row names the worker: hostname as node, its pid; no Ray address."""
    run_study(parse_spec(specs["ensemble"].replace("n = [60, 120]", "n = [60]")), tmp_path, LocalEngine(1))
    with sqlite3.connect(tmp_path / "study.sqlite") as con:
        rows = con.execute("SELECT host, node, address, pid FROM runs").fetchall()
    assert len(rows) == 2 and all(node == host == socket.gethostname() and address is None and pid not in (None, os.getpid())
                                  for host, node, address, pid in rows)


def test_a_store_written_before_the_placement_columns_gains_them(specs, tmp_path):
    """A store without runs.node/address and invocations.pid is extended in place; old rows keep NULL."""
    spec = parse_spec(specs["ensemble"].replace("n = [60, 120]", "n = [60]"))
    run_study(spec, tmp_path, InlineEngine())
    db = tmp_path / "study.sqlite"
    with sqlite3.connect(db) as con:
        for table, column in (("runs", "node"), ("runs", "address"), ("invocations", "pid")):
            con.execute(f"ALTER TABLE {table} DROP COLUMN {column}")
    result = run_study(parse_spec(specs["ensemble"]), tmp_path, InlineEngine())
    with sqlite3.connect(db) as con:
        nodes = [r[0] for r in con.execute("SELECT node FROM runs ORDER BY id")]
    assert result.ran == 2 and nodes[:2] == [None, None] and all(nodes[2:])


def test_a_listener_that_is_not_ray_is_refused_quickly():
    """A port that accepts but never answers as gRPC is refused after the timeout, not waited on for minutes."""
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen()
        with pytest.raises(InputError, match="does not answer") as err:
            check_reachable(f"127.0.0.1:{server.getsockname()[1]}", timeout=0.5)
    assert err.value.field == "--address"
