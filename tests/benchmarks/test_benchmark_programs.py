"""The benchmark programs: a real parser (--help runs nothing), output under --out, committed results untouched."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
BENCHMARKS = sorted(p for p in (ROOT / "benchmarks").glob("*.py") if not p.name.startswith("_"))
RESULTS = ROOT / "benchmarks" / "results"


def _results_state() -> dict:
    return {str(p): p.stat().st_mtime_ns for p in RESULTS.rglob("*") if p.is_file()}


def _run(script: Path, *args: str, cwd: Path, timeout: float = 120) -> subprocess.CompletedProcess:
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    return subprocess.run([sys.executable, str(script), *args], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=timeout)


@pytest.mark.parametrize("script", BENCHMARKS, ids=lambda p: p.stem)
def test_help_prints_usage_and_runs_nothing(script, tmp_path):
    """`--help` exits 0 with a usage naming --out, writes no file anywhere and leaves the results alone."""
    before = _results_state()
    proc = _run(script, "--help", cwd=tmp_path, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("usage:") and "--out DIR" in proc.stdout
    assert list(tmp_path.iterdir()) == [] and _results_state() == before


def test_default_output_goes_under_out_benchmarks_not_the_committed_results(tmp_path):
    """Without --out a benchmark writes ./out/benchmarks/NAME.json, never benchmarks/results."""
    before = _results_state()
    proc = _run(ROOT / "benchmarks" / "wire.py", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert json.loads((tmp_path / "out" / "benchmarks" / "wire.json").read_text())["benchmark"] == "wire"
    assert _results_state() == before


def test_admm_loss_seeds_writes_into_the_given_folder(tmp_path):
    """admm_loss_seeds.py takes --out DIR (created) and writes its JSON there."""
    out = tmp_path / "deep" / "dir"
    before = _results_state()
    proc = _run(ROOT / "benchmarks" / "admm_loss_seeds.py", "--seeds", "1", "--steps", "2", "--loss", "0.3",
                "--out", str(out), cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    result = json.loads((out / "admm_loss_seeds.json").read_text())
    assert result["parameters"]["losses"] == [0.3] and _results_state() == before
