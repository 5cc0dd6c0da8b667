"""Nothing outlives a command: SIGKILL of `study` or `launch` at a random moment leaves no process and no key.

Every process a trial starts carries a tag in its environment (inherited by workers, agents and the
resource tracker), so the check finds them all by scanning ``/proc``, whoever their parent is now.
The default suite runs one trial of each; ``-m slow`` runs ten of each at seeded random moments.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import numpy as np
import pytest

from sims.io.log_json import write_log
from sims.simulation.scenarios import get_scenario, simulate

ROOT = Path(__file__).resolve().parents[3]
pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="scans /proc")

#: ensemble cells of a few tenths of a second each: a study busy for several seconds on two workers
STUDY_SPEC = """
name = "busy"
command = "ensemble"
[fixed]
shape = "triple"
[grid]
n = [200, 400]
seed = [1, 2, 3, 4, 5, 6, 7, 8]
"""


def _tagged(tag: str) -> list[int]:
    """Live (non-zombie) processes whose environment holds ``DECENTRAL_TEST_TAG=tag``."""
    needle = f"DECENTRAL_TEST_TAG={tag}".encode()
    out = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            if needle not in (entry / "environ").read_bytes().split(b"\0"):
                continue
            if (entry / "stat").read_text().rsplit(")", 1)[1].split()[0] == "Z":
                continue
        except OSError:
            continue
        out.append(int(entry.name))
    return out


def _settled(check, timeout: float = 15.0):
    """Poll ``check()`` until it returns something empty (returned) or ``timeout`` passes (the last value)."""
    deadline = time.monotonic() + timeout
    while True:
        value = check()
        if not value or time.monotonic() > deadline:
            return value
        time.sleep(0.1)


def _kill_at_random(argv: list[str], tmp: Path, delay: float, busy: int = 0) -> str:
    """Start the command, wait until ``busy`` tagged processes run (0: do not wait), then ``delay`` s, then SIGKILL."""
    tag = uuid.uuid4().hex
    env = {**os.environ, "DECENTRAL_TEST_TAG": tag, "TMPDIR": str(tmp), "OPENBLAS_NUM_THREADS": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "sims.cli.main", *argv], cwd=tmp, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 60
    while busy and len(_tagged(tag)) < busy and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.05)
    assert not busy or len(_tagged(tag)) >= busy, "the command never got busy"
    time.sleep(delay)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    return tag


def _study_trial(tmp: Path, delay: float, busy: int = 0) -> None:
    spec = tmp / "spec.toml"
    spec.write_text(STUDY_SPEC)
    tag = _kill_at_random(["study", str(spec), "-o", str(tmp / "out"), "--workers", "2"], tmp, delay, busy)
    left = _settled(lambda: _tagged(tag))
    assert not left, f"killed after {delay:.2f} s, still alive: {left}"


def _launch_trial(tmp: Path, log: Path, delay: float, busy: int = 0) -> None:
    scratch = tmp / "tmp"
    scratch.mkdir()
    tag = _kill_at_random(["launch", str(log), "-o", str(tmp / "est.json"), "--rate", "0.4", "--round-period",
                           "0.025"], scratch, delay, busy)
    left = _settled(lambda: _tagged(tag))
    assert not left, f"killed after {delay:.2f} s, still alive: {left}"
    files = _settled(lambda: list(scratch.rglob("*")))
    assert not files, f"killed after {delay:.2f} s, left {files}"


@pytest.fixture(scope="module")
def launch_log(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("log") / "log.json"
    write_log(path, simulate(get_scenario("multi", n_assemblies=3, steps=30), seed=1).log)
    return path


def test_a_study_killed_with_sigkill_leaves_no_worker(tmp_path):
    """SIGKILL of `study` while its two workers run cells: no worker and no resource tracker survives it."""
    _study_trial(tmp_path, 0.5, busy=3)  # the study and its two workers (and the tracker) are up


def test_a_launch_killed_with_sigkill_leaves_no_agent_and_no_key(tmp_path, launch_log):
    """SIGKILL of `launch` while its agents run: no agent survives, and its temporary folder is gone."""
    _launch_trial(tmp_path, launch_log, 1.0, busy=5)  # launch, its janitor and three agents are up


@pytest.mark.slow
def test_ten_studies_killed_at_random_moments_leave_nothing(tmp_path):
    """Ten SIGKILLs of `study` at seeded random moments (0.1-6 s): never a process left."""
    for i, delay in enumerate(np.random.default_rng(23).uniform(0.1, 6.0, 10)):
        trial = tmp_path / str(i)
        trial.mkdir()
        _study_trial(trial, float(delay))


@pytest.mark.slow
def test_ten_launches_killed_at_random_moments_leave_nothing(tmp_path, launch_log):
    """Ten SIGKILLs of `launch` at seeded random moments (0.05-8 s): never a process, a file or a key left."""
    for i, delay in enumerate(np.random.default_rng(24).uniform(0.05, 8.0, 10)):
        trial = tmp_path / str(i)
        trial.mkdir()
        _launch_trial(trial, launch_log, float(delay))
