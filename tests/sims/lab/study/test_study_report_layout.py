"""The report's reading rules: constants stated once, axes from zero, legends off the data, figures in a grid."""

from __future__ import annotations

import re
import sqlite3

import pytest

from sims.lab.study.plots import draw_metric, y_limits
from sims.lab.study.report import LABELS, plan, write_report
from sims.lab.study.summary import STEADY_RTOL, collapse_constant_columns, fmt, steady


def _label(name: str) -> str:
    return LABELS.get(name, name)


def test_exact_constants_are_one_steady_value():
    """coverage 1 in every run is stated as the exact value 1, without a range."""
    s = steady("coverage", [1.0, 1.0, 1.0])
    assert s is not None and s.exact and s.value == 1.0 and s.describe() == "1"


def test_null_in_every_run_is_stated_as_not_applicable():
    """A metric NULL in every run is constant and says it does not apply."""
    s = steady("certified", [None, None])
    assert s is not None and s.value is None and "not applicable" in s.describe()


def test_a_change_within_the_tolerance_is_stated_with_its_range():
    """Peak memory 67.77 -> 68.04 MB (0.4 %) is stated once, with both ends of its range."""
    s = steady("peak_mb", [67.77, 67.9, 68.04])
    assert s is not None and not s.exact and (s.low, s.high) == (67.77, 68.04)
    assert "67.77" in s.describe() and "68.04" in s.describe()


def test_a_real_change_or_a_partly_null_metric_varies():
    """A change beyond the tolerance, or NULL beside numbers, is not steady."""
    assert steady("pos_error_m", [0.0165, 0.0300]) is None
    assert steady("x", [1.0, 1.0 + 3 * STEADY_RTOL]) is None
    assert steady("messages", [None, 12]) is None


def test_columns_that_read_the_same_in_every_row_are_taken_out():
    """Constant columns (as formatted) leave the table and come back as (name, value); kept columns stay."""
    head = ["loss", "runs", "coverage", "pos"]
    rows = [[0.0, 8, 1.0, 0.016], [0.3, 8, 1.0, 0.021]]
    h, r, constants = collapse_constant_columns(head, rows, keep=1)
    assert h == ["loss", "pos"] and r == [[0.0, 0.016], [0.3, 0.021]]
    assert constants == [("runs", 8), ("coverage", 1.0)]


def test_kept_columns_and_one_row_tables_are_not_collapsed():
    """The first `keep` columns stay even when constant; a one-row table keeps everything."""
    h, _, constants = collapse_constant_columns(["mode", "x"], [["admm", 1], ["admm", 2]], keep=1)
    assert h == ["mode", "x"] and constants == []
    h, r, constants = collapse_constant_columns(["a", "b"], [[1, 2]])
    assert h == ["a", "b"] and r == [[1, 2]] and constants == []


def test_table_cells_are_read_at_four_significant_digits():
    """Cells print as a reader reads them: 4 significant digits, separators, a dash for NULL."""
    assert [fmt(v) for v in (0.0164753, 68.04, 1227446.0, 3449, None, 1.0)] == \
        ["0.01648", "68.04", "1,227,446", "3,449", "—", "1"]


@pytest.mark.parametrize("values, expected", [
    ([67.77, 68.04], (0.0, 68.04 * 1.08)),   # non-negative: from zero
    ([-5.0, -2.0], (-5.0 * 1.08, 0.0)),      # non-positive: up to zero
    ([0.0, 0.0], (0.0, 1.0)),                # all zero: a unit range, not a degenerate one
])
def test_linear_y_axes_include_zero(values, expected):
    """A linear y axis includes zero, so a 0.4 % change is not drawn as a cliff."""
    assert y_limits(values) == pytest.approx(expected)


def test_y_axes_spanning_zero_or_logarithmic_are_automatic():
    """Values on both sides of zero already include it; a log axis cannot: both left automatic."""
    assert y_limits([-1.0, 2.0]) is None
    assert y_limits([1.0, 100.0], log=True) is None


def _rows(n_seeds: int = 3) -> list[dict]:
    rows = []
    for loss in (0.0, 0.3):
        for mode in ("admm", "centralized"):
            for seed in range(n_seeds):
                rows.append({"loss": loss, "mode": mode, "seed": seed, "scenario": "multi", "coverage": 1.0,
                             "pos_error_m": 0.01 + loss * (seed + 1) / 10, "peak_mb": 67.77 + 0.01 * seed,
                             "certified": None})
    return rows


def test_plan_states_constants_and_plots_what_varies_against_numeric_sweeps():
    """Fixed keys and steady metrics are stated; seeds are replicates; figures are drawn against loss only."""
    p = plan(["scenario", "loss", "mode", "seed"], ["pos_error_m", "coverage", "peak_mb", "certified"], _rows())
    assert {s.name for s in p.stated} == {"scenario", "coverage", "peak_mb", "certified"}
    assert p.replicates == {"seed": [0, 1, 2]} and p.swept == ["loss", "mode"]
    assert p.axes == ["loss"] and p.plotted == ["pos_error_m"]


def test_legends_sit_below_the_axes():
    """With several series the legend is drawn entirely below the plotting area, never over the data."""
    import matplotlib.pyplot as plt

    fig, _ = draw_metric("pos_error_m", "loss", ["mode"], _rows(), _label)
    try:
        fig.canvas.draw()
        ax = fig.axes[0]
        legend = ax.get_legend()
        assert legend is not None
        assert legend.get_window_extent().y1 <= ax.get_window_extent().y0
        assert ax.get_ylim()[0] == 0.0
    finally:
        plt.close(fig)


def _store(tmp_path, rows: list[dict]) -> None:
    cols = list(rows[0])
    with sqlite3.connect(tmp_path / "study.sqlite") as con:
        con.execute(f"CREATE TABLE runs (status TEXT, error TEXT, {', '.join(cols)})")
        for r in rows:
            con.execute(f"INSERT INTO runs VALUES ('ok', NULL, {', '.join('?' for _ in cols)})", tuple(r.values()))


def test_report_puts_figures_in_a_grid_and_states_constants_once(tmp_path):
    """Figures sit in a CSS grid; constant metrics get no figure and appear once, in the stated table."""
    _store(tmp_path, _rows())
    result = write_report(tmp_path)
    page = result.html.read_text()
    assert "grid-template-columns" in page
    grid = re.search(r'<div class="grid">(.*?)</div>', page, re.S).group(1)
    assert grid.count("<figure>") == len(result.figures) == 1
    assert {p.name for p in result.figures} == {"pos_error_m_vs_loss.png"}
    stated = re.search(r"The same in every run</h2>.*?</table>", page, re.S).group(0)
    assert "coverage" in stated and "peak memory" in stated and "67.77" in stated
    assert "vs_mode" not in page  # a category beside a numeric sweep is a colour, not an axis


@pytest.mark.slow
def test_the_report_screenshot_is_a_full_width_page(tmp_path):
    """benchmarks/screenshot_report.py renders report.html in headless Chromium: a 1280 px wide, non-blank PNG."""
    import subprocess
    import sys
    from pathlib import Path

    from PIL import Image

    script = Path(__file__).resolve().parents[4] / "benchmarks" / "screenshot_report.py"
    spec = _load_script(script)
    if spec.find_chromium() is None:
        pytest.skip("no chromium on PATH")
    _store(tmp_path, _rows())
    proc = subprocess.run([sys.executable, str(script), str(tmp_path), "--out", str(tmp_path / "shots"),
                           "--height", "900"], capture_output=True, text=True, timeout=180)
    assert proc.returncode == 0, proc.stderr
    with Image.open(tmp_path / "shots" / "report_screenshot.png") as im:
        assert im.size == (1280, 900)
        assert len(im.convert("L").getcolors(256) or ()) > 8  # text and plots, not a blank page


def _load_script(path):
    """Import a script by its path (benchmarks/ is not a package)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_logs_sharing_a_file_name_stay_apart_in_the_table(tmp_path):
    """Two recorded logs both called log.json appear by the paths written in the spec, not by file name."""
    rows = [{"log": f"runs/{day}/log.json", "window": w, "pos_error_m": 0.01 * w + (day == "b") * 0.003}
            for day in ("a", "b") for w in (1, 5)]
    _store(tmp_path, rows)
    page = write_report(tmp_path).html.read_text()
    table = page[page.index("Medians per setting"):]
    assert "runs/a/log.json" in table and "runs/b/log.json" in table
