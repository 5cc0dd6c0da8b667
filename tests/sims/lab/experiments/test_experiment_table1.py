"""The Table I / Fig. 4 experiment commands: result structure, table and plots, and a small real run."""

import json

import numpy as np

import pytest

from sims.cli.main import main
from sims.lab.experiments.table1 import TableConfig, plot_reconfig, plot_table1, run_table1, table_markdown

FAKE = {
    "table_mean_over_seeds": {
        "Ours (window K=5)": {"position_m": 0.04, "relative_position_pct": 2.0, "yaw_deg": 6.0, "coverage": 0.5, "fps": 20.0},
        "Ours (K=5, yaw std < 0.3 rad)": {"position_m": 0.03, "relative_position_pct": 1.5, "yaw_deg": 5.0, "coverage": 0.4, "fps": 20.0},
        "Bearing (root node)": {"position_m": 0.5, "relative_position_pct": 20.0, "yaw_deg": 20.0, "coverage": 0.3, "fps": 20.0},
        "AprilTag (root tag pose)": {"position_m": None, "relative_position_pct": None, "yaw_deg": None, "coverage": 0.0, "fps": 15.0},
    }
}


def test_markdown_table_marks_missing_values():
    """The Markdown table has one row per method and '/' where a method placed nothing."""
    md = table_markdown(FAKE)
    assert md.count("\n") == 2 + len(FAKE["table_mean_over_seeds"])
    assert "| AprilTag (root tag pose) | / | / | / | 0 % | 15.0 |" in md


def test_plots_are_written(tmp_path):
    """Both plots write a PNG file, also with missing values."""
    plot_table1(FAKE, tmp_path / "t.png")
    series = {"A1": {"t": [0.0, 0.2], "position_m": [None, 0.1], "yaw_deg": [None, 3.0],
                     "identified_nodes": [0, 2], "configured_nodes": [3, 3]}}
    plot_reconfig({"series": series}, tmp_path / "r.png")
    assert (tmp_path / "t.png").stat().st_size > 1000 and (tmp_path / "r.png").stat().st_size > 1000


def test_bad_arguments_exit_2(tmp_path, capsys):
    """Too few steps ends with exit 2 naming --steps and nothing written."""
    assert main(["experiment", "table1", "-o", str(tmp_path / "x"), "--steps", "2"]) == 2
    assert "--steps" in capsys.readouterr().err
    assert not (tmp_path / "x" / "table1.json").exists()


@pytest.mark.slow
def test_small_rendered_run_places_targets_and_beats_bearing():
    """A 1-seed, 20-step rendered run places targets with ours, more accurately than the bearing baseline."""
    result = run_table1(TableConfig(seeds=1, steps=20))
    json.dumps(result, allow_nan=False)
    table = result["table_mean_over_seeds"]
    ours, bearing = table["Ours (window K=5)"], table["Bearing (root node)"]
    assert ours["coverage"] > 0.2 and ours["position_m"] < 0.3
    assert bearing["position_m"] is None or ours["position_m"] < bearing["position_m"]


def test_restricted_estimate_keeps_only_the_other_methods_placements():
    """Like-for-like scoring keeps ours' poses only at the (step, target) pairs the baseline placed."""
    from decentral.observations import Estimate, EstimateStep, PlanarPose
    from sims.lab.experiments.table1 import _restricted

    pose = PlanarPose(np.zeros(3), 0.0)
    ours = Estimate("A0", (EstimateStep(0.0, {"A1": pose, "A2": pose}), EstimateStep(0.2, {"A1": pose})), {})
    base = Estimate("A0", (EstimateStep(0.0, {"A2": pose}), EstimateStep(0.2, {})), {})
    kept = _restricted(ours, base)
    assert [set(s.poses) for s in kept.steps] == [{"A2"}, set()]
