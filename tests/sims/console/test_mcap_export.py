"""MCAP export: every channel comes back through the mcap reader, one message per step, each valid
against its JSON schema."""

from __future__ import annotations

import json
from collections import Counter

import pytest

pytest.importorskip("mcap", reason="the console extra (pip install 'decentral[console]') is not installed")

from mcap.reader import make_reader  # noqa: E402

from sims.console.mcap_export import SCHEMAS, write_streams_mcap, write_swarm_mcap  # noqa: E402
from sims.console.streams import StreamFollower  # noqa: E402
from sims.console.operator import OperatorSwarm  # noqa: E402
from sims.simulation.swarm import SwarmConfig  # noqa: E402


def _read(path):
    with open(path, "rb") as fh:
        reader = make_reader(fh)
        out = [(schema, channel, msg) for schema, channel, msg in reader.iter_messages()]
    return out


def test_swarm_export_holds_every_channel_every_step(tmp_path):
    """Truth, estimates, detections, network and errors each have one message per step, in time order."""
    op = OperatorSwarm(SwarmConfig(n_robots=4, arena=3.0, dt=0.2), 1, auto=True)
    path = tmp_path / "run.mcap"
    start = op.truth()
    n = write_swarm_mcap(path, op, 12)
    msgs = _read(path)
    count = Counter(ch.topic for _, ch, _ in msgs)
    assert count == {t: 12 for t in ("/truth", "/estimates", "/detections", "/network", "/errors")} and n == 60
    times = [m.log_time for _, ch, m in msgs if ch.topic == "/truth"]
    assert times == sorted(times) and len(set(times)) == 12
    first = [json.loads(m.data) for _, ch, m in msgs if ch.topic == "/truth"][0]
    assert [v for r in first["robots"] for v in (r["x"], r["y"], r["theta"])] == pytest.approx(start.ravel().tolist())


def test_every_message_matches_its_channel_schema(tmp_path):
    """Each channel declares a JSON schema (encoding jsonschema) that its messages validate against."""
    jsonschema = pytest.importorskip("jsonschema")
    op = OperatorSwarm(SwarmConfig(n_robots=3, arena=3.0, dt=0.2), 2, auto=True)
    path = tmp_path / "run.mcap"
    write_swarm_mcap(path, op, 4)
    for schema, channel, msg in _read(path):
        assert schema.encoding == "jsonschema" and channel.message_encoding == "json"
        assert json.loads(schema.data) == SCHEMAS[schema.name]
        jsonschema.validate(json.loads(msg.data), SCHEMAS[schema.name])


def test_streams_export_has_one_channel_per_agent(tmp_path):
    """Each agent's stream records become the messages of /agents/<NAME>."""
    for name in ("A0", "A1"):
        (tmp_path / f"{name}.0.jsonl").write_text("".join(
            json.dumps({"step": k, "t": 0.2 * k, "poses": {}}) + "\n" for k in range(3)))
    f = StreamFollower([tmp_path])
    f.poll()
    write_streams_mcap(tmp_path / "s.mcap", f)
    assert Counter(ch.topic for _, ch, _ in _read(tmp_path / "s.mcap")) == {"/agents/A0": 3, "/agents/A1": 3}


def test_an_interrupted_export_leaves_no_file(tmp_path):
    """A failure while writing removes the partial file instead of leaving half an MCAP."""
    class Broken:
        names = ("R0",)

        def __getattr__(self, name):
            raise RuntimeError("boom")

    with pytest.raises(RuntimeError):
        write_swarm_mcap(tmp_path / "x.mcap", Broken(), 2)
    assert list(tmp_path.iterdir()) == []
