"""Shared small studies for the study tests (cells of a few tenths of a second)."""

from __future__ import annotations

import os
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[4]

#: four ensemble cells of ~0.1-0.3 s
ENSEMBLE_SPEC = """
name = "tiny-ensembles"
command = "ensemble"
[fixed]
shape = "triple"
[grid]
n = [60, 120]
seed = [1, 2]
"""

#: localize cells over a short ADMM run; the reference "nobody" makes every cell with it fail
LOCALIZE_SPEC = """
name = "tiny-loss"
command = "localize"
[fixed]
scenario = "multi"
n_assemblies = 2
steps = 4
mode = "admm"
[grid]
loss = [0.0, 0.3]
reference = ["A0", "nobody"]
seed = [1]
"""


@pytest.fixture
def write_spec(tmp_path):
    """Write a spec's text to a file in ``tmp_path`` and return its path."""

    def write(text: str, name: str = "spec.toml") -> Path:
        path = tmp_path / name
        path.write_text(text)
        return path

    return write


def _cli(*args: str, env: dict | None = None, timeout: float = 120) -> subprocess.CompletedProcess:
    full_env = {**os.environ, **(env or {})}
    return subprocess.run([sys.executable, "-m", "sims.cli.main", *args], capture_output=True, text=True,
                          cwd=ROOT, env=full_env, timeout=timeout)


def _rows(db: Path, columns: str = "*") -> list[tuple]:
    with sqlite3.connect(db) as con:
        return con.execute(f"SELECT {columns} FROM runs ORDER BY cell_key").fetchall()


@pytest.fixture
def cli():
    """``cli(*args, env=None)``: run ``decentral ARGS`` in a fresh interpreter, as a user would."""
    return _cli


@pytest.fixture
def rows():
    """``rows(db, columns="*")``: every row of ``runs``, ordered by cell key."""
    return _rows


@pytest.fixture
def specs() -> dict[str, str]:
    """The texts of the two small studies: ``specs["ensemble"]``, ``specs["localize"]``."""
    return {"ensemble": ENSEMBLE_SPEC, "localize": LOCALIZE_SPEC}
