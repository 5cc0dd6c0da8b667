"""The report is made from the database alone: a copied store, or a bare hand-made ``runs`` table."""

from __future__ import annotations

import base64
import re
import shutil
import sqlite3

import numpy as np
import pytest

from decentral.errors import InputError
from sims.lab.study.engines import LocalEngine
from sims.lab.study.fits import fit_log, fit_power
from sims.lab.study.report import write_report
from sims.lab.study.runner import run_study
from sims.lab.study.spec import parse_spec


def _embedded_pngs(html: str) -> list[bytes]:
    return [base64.b64decode(m) for m in re.findall(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"', html)]


def test_report_renders_from_a_copied_database_alone(specs, tmp_path):
    """A store copied into an empty folder gives report.html with every figure embedded and written beside it."""
    run_study(parse_spec(specs["localize"]), tmp_path / "made", LocalEngine(2))
    alone = tmp_path / "alone"
    alone.mkdir()
    shutil.copy(tmp_path / "made" / "study.sqlite", alone / "study.sqlite")
    result = write_report(alone)
    html = result.html.read_text()
    pngs = _embedded_pngs(html)
    assert len(pngs) == len(result.figures) > 0 and all(p.startswith(b"\x89PNG") for p in pngs)
    assert all(path.exists() and path.parent == alone for path in result.figures)
    assert (alone / "messages_vs_loss.png").exists()
    assert "message loss probability" in html and "position error [m]" in html  # a reader's labels
    assert "Failed cells" in html and "nobody" in html and "tiny-loss" in html
    assert "<script" not in html and "http" not in html.replace("http-equiv", "")  # self-contained


def test_report_from_a_hand_made_runs_table_fits_messages_and_time_against_size(tmp_path):
    """A bare runs table (no other table or file) is enough; size sweeps get the a + b ln N and power fits."""
    rng = np.random.default_rng(0)
    with sqlite3.connect(tmp_path / "study.sqlite") as con:
        con.execute("CREATE TABLE runs (n INTEGER, seed INTEGER, status TEXT, error TEXT, seconds REAL, "
                    "messages_per_module REAL, global_rms REAL)")
        for n in (250, 1000, 4000, 16000):
            for seed in range(3):
                con.execute("INSERT INTO runs VALUES (?, ?, 'ok', NULL, ?, ?, ?)",
                            (n, seed, 1e-3 * n ** 1.1 * (1 + 0.05 * rng.standard_normal()),
                             -3000 + 640 * np.log(n) + rng.normal(0, 5), 0.8 + 0.1 * rng.random()))
    result = write_report(tmp_path)
    html = result.html.read_text()
    names = {p.name for p in result.figures}
    assert {"messages_per_module_vs_n.png", "seconds_vs_n.png", "global_rms_vs_n.png"} <= names
    assert "ln N" in html and re.search(r"N\^1\.\d", html) and "R²" in html


def test_report_of_a_missing_store_is_a_bad_input(tmp_path):
    """No study.sqlite: InputError naming the file, nothing written."""
    with pytest.raises(InputError, match="study.sqlite"):
        write_report(tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_fits_recover_known_laws():
    """fit_log and fit_power recover the coefficients of exact data with R² = 1."""
    n = np.array([100.0, 1000.0, 10000.0])
    log = fit_log(n, 5 + 2 * np.log(n))
    power = fit_power(n, 3 * n ** 1.5)
    assert log.a == pytest.approx(5) and log.b == pytest.approx(2) and log.r2 == pytest.approx(1)
    assert power.a == pytest.approx(3) and power.b == pytest.approx(1.5) and power.r2 == pytest.approx(1)
    assert fit_log([5.0, 5.0], [1.0, 2.0]) is None
