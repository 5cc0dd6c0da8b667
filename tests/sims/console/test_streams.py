"""Following agents' JSONL streams while they are written: whole lines only, defensively, restarts win."""

from __future__ import annotations

import json

from sims.console.streams import StreamFollower, record_pose
from sims.console.views import launch_rows, launch_series


def _rec(step, x, **extra):
    return json.dumps({"step": step, "t": 0.2 * step, "poses": {"A1": {"p": [x, 0.0, 0.0], "theta": 0.1}},
                       "converged": True, "rounds": 4,
                       "counts": {"messages": 10 * step, "bytes": 100 * step, "rejected": {"replay": 1}}, **extra})


def test_a_line_still_being_written_waits_for_its_newline(tmp_path):
    """A record without its newline is not read until the rest of it arrives."""
    f = tmp_path / "A0.0.jsonl"
    line = _rec(0, 1.0)
    f.write_text(_rec(1, 1.0)[:0] + line[:20])
    s = StreamFollower([tmp_path])
    assert s.poll() == 0
    with open(f, "a") as fh:
        fh.write(line[20:] + "\n")
    assert s.poll() == 1 and record_pose(s.agents["A0"].latest(), "A1") == (1.0, 0.0, 0.1)


def test_bad_lines_are_counted_and_skipped(tmp_path):
    """Lines that are not JSON objects with a step are counted, and the good ones around them read."""
    (tmp_path / "A0.jsonl").write_text(_rec(0, 1.0) + "\nnot json\n[1, 2]\n{\"t\": 3}\n" + _rec(1, 2.0) + "\n")
    s = StreamFollower([tmp_path / "A0.jsonl"])
    assert s.poll() == 2 and s.bad_lines == 3 and sorted(s.agents["A0"].steps) == [0, 1]


def test_a_restarted_process_replaces_the_steps_it_reports_again(tmp_path):
    """The newer incarnation's record of a step wins; restarts are counted."""
    (tmp_path / "A2.0.jsonl").write_text(_rec(0, 1.0) + "\n" + _rec(1, 1.0) + "\n")
    (tmp_path / "A2.1.jsonl").write_text(_rec(1, 5.0) + "\n")
    s = StreamFollower([tmp_path])
    s.poll()
    view = s.agents["A2"]
    assert record_pose(view.steps[1], "A1")[0] == 5.0 and view.incarnations == 2
    assert launch_rows(s, 0.0)[0]["restarts"] == 1


def test_rows_and_series_read_counts_rejections_and_provisional_steps(tmp_path):
    """An agent's row carries its counts and rejections by reason; provisional steps are listed; the
    series has one point per placed step."""
    (tmp_path / "A0.0.jsonl").write_text(_rec(0, 1.0, provisional=True) + "\n" + _rec(1, 2.0) + "\n")
    s = StreamFollower([tmp_path])
    s.poll()
    row = launch_rows(s, 0.0)[0]
    assert (row["messages"], row["bytes"], row["rejected"], row["provisional"]) == (10, 100, {"replay": 1}, [0])
    assert launch_series(s, "A1")["A0"] == [(0.0, 1.0), (0.2, 2.0)]


def test_malformed_poses_place_nobody():
    """A pose with missing or non-finite numbers is not placed (never a NaN on the page)."""
    assert record_pose({"poses": {"A1": {"p": [1.0], "theta": 0}}}, "A1") is None
    assert record_pose({"poses": {"A1": {"p": [1.0, float("nan"), 0], "theta": 0}}}, "A1") is None
    assert record_pose({"poses": "x"}, "A1") is None
