"""The console's top view as data and SVG: what is drawn is where the truth and the estimates are."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from sims.console.scene import ellipse_axes, loss_colour, svg
from sims.console.operator import OperatorSwarm
from sims.console.views import swarm_frame
from sims.simulation.swarm import SwarmConfig


def _attrs(text: str, cls: str) -> list[dict]:
    out = []
    for m in re.finditer(rf'<g class="{cls}"([^>]*)>', text):
        out.append(dict(re.findall(r'data-([a-z]+)="([^"]*)"', m.group(1))))
    return out


def test_every_robot_is_drawn_at_its_true_position():
    """The SVG has one truth group per robot, at the world position of the swarm's state."""
    op = OperatorSwarm(SwarmConfig(n_robots=7, dt=0.1), 2)
    text = svg(swarm_frame(op, "R3"))
    drawn = {a["robot"]: (float(a["x"]), float(a["y"])) for a in _attrs(text, "truth")}
    state = op.truth()
    assert set(drawn) == set(op.names)
    for i, n in enumerate(op.names):
        assert drawn[n] == pytest.approx(tuple(state[i, :2]), abs=1e-3)


def test_estimates_are_drawn_where_the_observer_places_them():
    """Each estimate mark sits at the observer's estimate carried into the world by the observer's true pose."""
    op = OperatorSwarm(SwarmConfig(n_robots=4, dt=0.1, dropout=0.0), 8)
    op.picture("R1")
    op.tick()
    text = svg(swarm_frame(op, "R1", mode="by"))
    marks = _attrs(text, "est")
    assert marks and all(m["observer"] == "R1" for m in marks)
    i = op.index["R1"]
    s = op.truth()[i]
    c, sn = math.cos(s[2]), math.sin(s[2])
    for m in marks:
        tr = op.sim.robots["R1"].estimate(m["target"])
        want = (s[0] + c * tr.mean[0] - sn * tr.mean[1], s[1] + sn * tr.mean[0] + c * tr.mean[1])
        assert (float(m["x"]), float(m["y"])) == pytest.approx(want, abs=1e-3)


def test_ellipse_axes_of_a_rotated_diagonal_covariance():
    """The 2-sigma ellipse of R diag(4, 1) R^T has semi-axes 4 and 2 along R's columns."""
    a = math.radians(30)
    R = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    big, small, ang = ellipse_axes(R @ np.diag([4.0, 1.0]) @ R.T)
    assert (big, small) == pytest.approx((4.0, 2.0)) and math.radians(ang) % math.pi == pytest.approx(a)


def test_loss_colours_run_from_green_to_red_and_grey_for_silence():
    """No loss is green, total loss is red, an unused link grey."""
    assert loss_colour(0.0).startswith("#00") and loss_colour(1.0).startswith("#ff00")
    assert loss_colour(None) == loss_colour(float("nan")) == "#bbbbbb"


def test_error_panel_has_a_line_per_robot_or_the_selected_one_and_the_median():
    """Up to twelve robots each get an error line (None while tracking nobody); beyond, the selected
    robot's line and the median only."""
    from sims.console.views import error_series

    op = OperatorSwarm(SwarmConfig(n_robots=4, dt=0.1, dropout=0.0), 8)
    op.picture("R1")
    op.tick()
    lines = error_series(op, "R1")
    assert set(lines) == {"R0", "R1", "R2", "R3", "median"}
    assert lines["R0"][-1][1] is None and lines["R1"][-1][1] == pytest.approx(op.history[-1].error[1], abs=1e-4)
    big = OperatorSwarm(SwarmConfig(n_robots=13, dt=0.1), 1)
    assert set(error_series(big, "R5")) == {"R5", "median"}
