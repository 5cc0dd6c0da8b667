"""A finished run replayed: estimates against the true relative poses, step by step, and as MCAP."""

from __future__ import annotations

import json
from collections import Counter

import numpy as np
import pytest

from decentral.errors import InputError
from decentral.metrics import GroundTruth
from decentral.observations import Estimate, EstimateStep, ObservationLog, PlanarPose, Step
from sims.console.views import Replay


def _run():
    cfg = {"A0": {0: np.zeros(3)}, "A1": {1: np.zeros(3), 2: np.array([0.2, 0.0, 0.0])}}
    log = ObservationLog(0.06, ("A0", "A1"), {}, (Step(0.0, cfg), Step(0.2, cfg)))
    est = Estimate("A0", (EstimateStep(0.0, {"A1": PlanarPose(np.array([1.0, 0.0, 0.0]), 0.0)}),
                          EstimateStep(0.2, {"A1": PlanarPose(np.array([1.1, 0.0, 0.0]), 0.0)})), {})
    eye = np.stack([np.eye(3)] * 2)
    # A0 at (2, 1) facing +x; A1 one metre ahead of it at both steps
    truth = GroundTruth(np.array([0.0, 0.2]), {"A0": eye, "A1": eye},
                        {"A0": np.array([[2.0, 1.0, 0.06]] * 2), "A1": np.array([[3.0, 1.0, 0.06]] * 2)})
    return log, est, truth


def test_replay_marks_carry_their_error_against_the_true_relative_pose():
    """Each step's estimate is drawn in the reference's frame with its distance to the truth there."""
    replay = Replay(*_run())
    errors = [replay.frame(k).marks[0].error for k in range(len(replay))]
    assert errors == pytest.approx([0.0, 0.1])
    outline = replay.frame(1).truth_marks[0]
    assert (outline.name, outline.x, outline.y) == ("A1", pytest.approx(1.0), pytest.approx(0.0))


def test_replay_draws_an_assemblys_nodes_at_its_estimated_pose():
    """The nodes of the log's configuration are placed by the estimated pose."""
    body = [b for b in Replay(*_run()).frame(1).bodies if b.name == "A1"][0]
    assert sorted(body.nodes) == [pytest.approx((1.1, 0.0)), pytest.approx((1.3, 0.0))]


def test_an_estimate_without_steps_is_refused():
    """Nothing to replay is an input error, not an empty page."""
    log, est, truth = _run()
    with pytest.raises(InputError):
        Replay(log, Estimate("A0", (), {}), truth)


def test_replay_mcap_has_the_estimate_and_the_truth(tmp_path):
    """The replay's MCAP holds /estimate and /truth, one message per step."""
    pytest.importorskip("mcap", reason="the console extra (pip install 'decentral[console]') is not installed")
    from mcap.reader import make_reader

    from sims.console.mcap_export import write_replay_mcap

    write_replay_mcap(tmp_path / "r.mcap", Replay(*_run()))
    with open(tmp_path / "r.mcap", "rb") as fh:
        msgs = [(ch.topic, json.loads(m.data)) for _, ch, m in make_reader(fh).iter_messages()]
    assert Counter(t for t, _ in msgs) == {"/estimate": 2, "/truth": 2}
    assert [m["poses"][0]["x"] for t, m in msgs if t == "/estimate"] == pytest.approx([1.0, 1.1])
