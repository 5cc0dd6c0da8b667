"""A real Ray cluster on loopback (`ray start --head`): the CLI joins it at HEAD:PORT and through ray://.

Slow (a head node starts in 10-30 s on a busy machine). The head runs with ``--block`` in a process
group of its own, and that group alone is stopped afterwards: no other Ray on the machine is touched.
"""

from __future__ import annotations

import os
import re
import signal
import socket
import sqlite3
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

pytest.importorskip("ray")
pytest.importorskip("grpc")  # Ray Client needs ray[client]

pytestmark = pytest.mark.slow

#: Ray's token authentication (on by default for new clusters), with a token of this test's own
AUTH = {"RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": os.urandom(16).hex()}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_for(port: int, deadline: float) -> bool:
    while time.monotonic() < deadline:
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=1):
                return True
        except OSError:
            time.sleep(0.5)
    return False


@pytest.fixture(scope="module")
def head():
    """A one-CPU Ray head on 127.0.0.1: ``(gcs port, client port)``; its process group is stopped afterwards."""
    ray_bin = Path(sys.executable).with_name("ray")
    gcs, client = _free_port(), _free_port()
    temp = tempfile.mkdtemp(prefix="ray-head-")
    env = {**os.environ, **AUTH, "RAY_USAGE_STATS_ENABLED": "0"}
    proc = subprocess.Popen([str(ray_bin), "start", "--head", "--block", "--node-ip-address=127.0.0.1",
                             f"--port={gcs}", f"--ray-client-server-port={client}", "--num-cpus=1",
                             "--include-dashboard=false", "--disable-usage-stats", f"--temp-dir={temp}"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        if not (_wait_for(gcs, deadline) and _wait_for(client, deadline)):
            pytest.skip("the Ray head did not start within 120 s")
        yield gcs, client
    finally:
        try:
            os.killpg(proc.pid, signal.SIGTERM)
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        except ProcessLookupError:
            pass


@pytest.mark.parametrize("scheme", ["", "ray://"])
def test_the_cli_runs_a_study_on_a_running_cluster(head, scheme, specs, tmp_path, cli):
    """`decentral study --engine ray --address` at HEAD:PORT and at ray://HEAD:CLIENT_PORT: every cell ok."""
    gcs, client = head
    address = f"ray://127.0.0.1:{client}" if scheme else f"127.0.0.1:{gcs}"
    spec = tmp_path / "spec.toml"
    spec.write_text(specs["ensemble"])
    proc = cli("study", str(spec), "-o", str(tmp_path / "out"), "--engine", "ray", "--address", address,
               env=AUTH, timeout=300)
    assert proc.returncode == 0, proc.stderr
    with sqlite3.connect(tmp_path / "out" / "study.sqlite") as con:
        rows = con.execute("SELECT status, engine, address, node FROM runs").fetchall()
        invocation = con.execute("SELECT address, status FROM invocations").fetchone()
    assert len(rows) == 4 and all(r[:2] == ("ok", "ray") and re.fullmatch(r"\d+(\.\d+){3}", r[2])
                                  and re.fullmatch(r"[0-9a-f]{56}", r[3]) for r in rows)
    assert invocation == (address, "finished")


def test_a_cluster_that_wants_a_token_is_refused_in_one_line_saying_so(head, specs, tmp_path, cli):
    """Without the cluster's token: exit 2 and one line naming RAY_AUTH_MODE and RAY_AUTH_TOKEN."""
    spec = tmp_path / "spec.toml"
    spec.write_text(specs["ensemble"])
    proc = cli("study", str(spec), "-o", str(tmp_path / "out"), "--engine", "ray", "--address",
               f"127.0.0.1:{head[0]}", env={"RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": "0" * 32}, timeout=300)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1 and "RAY_AUTH_TOKEN" in lines[0], proc.stderr
