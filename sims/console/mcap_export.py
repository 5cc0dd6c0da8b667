"""The console's streams as an MCAP file: JSON messages with JSON-schema channels (Foxglove and Rerun
open them), timestamped with the run's time (``log_time`` = simulated or log seconds, in ns).

Swarm channels (one message per step): ``/truth``, ``/estimates``, ``/detections``, ``/network``,
``/errors``. Streams of running agents: ``/agents/<NAME>`` (one per stream record). Replay of a
finished run: ``/estimate`` and, with the truth, ``/truth``. The schemas are :data:`SCHEMAS`;
docs/console.md lists them.
"""

from __future__ import annotations

import json
import math
import os

import numpy as np

__all__ = ["SCHEMAS", "McapSink", "write_swarm_mcap", "write_streams_mcap", "write_replay_mcap"]

_num = {"type": "number"}
_pose = {"type": "object", "properties": {"name": {"type": "string"}, "x": _num, "y": _num, "theta": _num},
         "required": ["name", "x", "y", "theta"]}
#: JSON schema of every channel, by schema name
SCHEMAS = {
    "decentral.swarm.Truth": {
        "type": "object", "description": "True pose of every robot in the world frame W (m, rad)",
        "properties": {"step": {"type": "integer"}, "t": _num, "robots": {"type": "array", "items": _pose}},
        "required": ["step", "t", "robots"]},
    "decentral.swarm.Estimates": {
        "type": "object",
        "description": "Each robot's estimate of each other robot, in the observer's own frame (m, rad); "
                       "cov is the row-major 3x3 covariance of (x, y, theta)",
        "properties": {"step": {"type": "integer"}, "t": _num, "estimates": {"type": "array", "items": {
            "type": "object", "properties": {"observer": {"type": "string"}, "target": {"type": "string"},
                                             "x": _num, "y": _num, "theta": _num,
                                             "cov": {"type": "array", "items": _num, "minItems": 9, "maxItems": 9},
                                             "yaw_known": {"type": "boolean"}, "source": {"type": "string"},
                                             "error_m": _num},
            "required": ["observer", "target", "x", "y", "theta", "cov"]}}},
        "required": ["step", "t", "estimates"]},
    "decentral.swarm.Detections": {
        "type": "object", "description": "Identified circles (px) in the pictures taken at this step",
        "properties": {"step": {"type": "integer"}, "t": _num, "pictures": {"type": "array", "items": {
            "type": "object", "properties": {"robot": {"type": "string"}, "detections": {"type": "array", "items": {
                "type": "object", "properties": {"id": {"type": "integer"}, "u": _num, "v": _num, "r": _num}}}}}}},
        "required": ["step", "t", "pictures"]},
    "decentral.swarm.Network": {
        "type": "object", "description": "Radio counters so far (copies and bytes), per robot, and recent link loss",
        "properties": {"step": {"type": "integer"}, "t": _num, "total": {"type": "object"},
                       "per_robot": {"type": "object"}, "stale_discarded": {"type": "integer"},
                       "recent_loss_mean": {"type": ["number", "null"]}},
        "required": ["step", "t", "total", "per_robot"]},
    "decentral.swarm.Errors": {
        "type": "object", "description": "Per observer, mean position error (m) of its estimates against truth "
                                         "(null: tracks nobody) and how many robots it tracks",
        "properties": {"step": {"type": "integer"}, "t": _num, "error_m": {"type": "object"},
                       "tracked": {"type": "object"}},
        "required": ["step", "t", "error_m", "tracked"]},
    "decentral.agent.StreamRecord": {
        "type": "object", "description": "One finished step of an agent, as its --stream wrote it (poses relative to "
                                         "the run's reference)",
        "properties": {"step": {"type": "integer"}, "t": _num, "poses": {"type": "object"},
                       "converged": {"type": ["boolean", "null"]}, "rounds": {"type": ["integer", "null"]},
                       "counts": {"type": "object"}},
        "required": ["step", "t"]},
    "decentral.replay.Poses": {
        "type": "object", "description": "Poses relative to the reference assembly's root frame (m, rad)",
        "properties": {"t": _num, "reference": {"type": "string"}, "poses": {"type": "array", "items": _pose}},
        "required": ["t", "reference", "poses"]},
}


class McapSink:
    """An MCAP writer with one JSON channel per topic (registered on first use)."""

    def __init__(self, path: str | os.PathLike):
        from mcap.writer import Writer

        self.path = os.fspath(path)
        self._tmp = self.path + ".part"
        self._fh = open(self._tmp, "wb")
        self.writer = Writer(self._fh)
        self.writer.start(profile="", library="decentral")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._seq: dict[str, int] = {}
        self.count = 0

    def write(self, topic: str, schema: str, t: float, payload: dict) -> None:
        if schema not in self._schemas:
            self._schemas[schema] = self.writer.register_schema(
                name=schema, encoding="jsonschema", data=json.dumps(SCHEMAS[schema]).encode())
        if topic not in self._channels:
            self._channels[topic] = self.writer.register_channel(topic=topic, message_encoding="json",
                                                                 schema_id=self._schemas[schema])
        ns = int(round(max(t, 0.0) * 1e9))
        seq = self._seq[topic] = self._seq.get(topic, -1) + 1
        self.writer.add_message(channel_id=self._channels[topic], log_time=ns, publish_time=ns, sequence=seq,
                                data=json.dumps(payload, allow_nan=False).encode())
        self.count += 1

    def close(self) -> None:
        """Finish the file and move it into place (an interrupted export leaves no half file)."""
        self.writer.finish()
        self._fh.close()
        os.replace(self._tmp, self.path)

    def abort(self) -> None:
        self._fh.close()
        if os.path.exists(self._tmp):
            os.remove(self._tmp)


def _fin(v) -> float | None:
    v = float(v)
    return v if math.isfinite(v) else None


def swarm_messages(op) -> list[tuple[str, str, dict]]:
    """``(topic, schema, payload)`` of the swarm's current step."""
    k, t = op.k, op.t
    state = op.truth()
    truth = {"step": k, "t": t, "robots": [{"name": n, "x": float(s[0]), "y": float(s[1]), "theta": float(s[2])}
                                           for n, s in zip(op.names, state)]}
    ests = []
    for obs in op.names:
        robot = op.sim.robots[obs]
        world = op.estimates_of(obs)
        for target, tr in robot.estimates().items():
            ests.append({"observer": obs, "target": target, "x": float(tr.mean[0]), "y": float(tr.mean[1]),
                         "theta": float(tr.mean[2]), "cov": [float(v) for v in np.ravel(tr.cov)],
                         "yaw_known": bool(tr.yaw_known), "source": tr.source, "error_m": world[target]["error"]})
    pics = [{"robot": n, "detections": [{"id": int(d.node), "u": float(d.u), "v": float(d.v), "r": float(d.r)}
                                        for d in dets]} for n, dets in sorted(op.detections.items())]
    counters = op.counters()
    loss = op.link_loss()
    fin = loss[np.isfinite(loss)]
    net = {"step": k, "t": t, "total": counters["total"], "per_robot": counters["per_robot"],
           "stale_discarded": counters["stale_discarded"], "recent_loss_mean": float(fin.mean()) if fin.size else None}
    rec = op.history[-1]
    errors = {"step": k, "t": t, "error_m": {n: _fin(e) for n, e in zip(op.names, rec.error)},
              "tracked": {n: int(c) for n, c in zip(op.names, rec.tracked)}}
    return [("/truth", "decentral.swarm.Truth", truth), ("/estimates", "decentral.swarm.Estimates", {
        "step": k, "t": t, "estimates": ests}), ("/detections", "decentral.swarm.Detections",
                                                 {"step": k, "t": t, "pictures": pics}),
            ("/network", "decentral.swarm.Network", net), ("/errors", "decentral.swarm.Errors", errors)]


def write_swarm_mcap(path, op, steps: int) -> int:
    """Run ``op`` for ``steps`` more steps (its own loop when ``op.auto``) and write every step; return
    the messages written."""
    sink = McapSink(path)
    try:
        for _ in range(steps):
            for topic, schema, payload in swarm_messages(op):
                sink.write(topic, schema, op.t, payload)
            op.tick()
        sink.close()
    except BaseException:
        sink.abort()
        raise
    return sink.count


def write_streams_mcap(path, follower) -> int:
    """Every stream record read so far as ``/agents/<NAME>``; return the messages written."""
    sink = McapSink(path)
    try:
        for name, view in sorted(follower.agents.items()):
            for k, rec in sorted(view.steps.items()):
                t = rec.get("t")
                payload = {key: v for key, v in rec.items() if not key.startswith("_")}
                sink.write(f"/agents/{name}", "decentral.agent.StreamRecord",
                           float(t) if isinstance(t, (int, float)) and math.isfinite(t) else 0.0, payload)
        sink.close()
    except BaseException:
        sink.abort()
        raise
    return sink.count


def write_replay_mcap(path, replay) -> int:
    """A finished run's estimate (and truth) as ``/estimate`` and ``/truth``; return the messages written."""
    sink = McapSink(path)
    try:
        for k in range(len(replay)):
            fr = replay.frame(k)
            t = replay.estimate.steps[k].t
            sink.write("/estimate", "decentral.replay.Poses", t, {"t": t, "reference": replay.reference, "poses": [
                {"name": m.target, "x": m.x, "y": m.y, "theta": m.theta} for m in fr.marks]})
            if fr.truth_marks:
                sink.write("/truth", "decentral.replay.Poses", t, {"t": t, "reference": replay.reference, "poses": [
                    {"name": b.name, "x": b.x, "y": b.y, "theta": b.theta} for b in fr.truth_marks]})
        sink.close()
    except BaseException:
        sink.abort()
        raise
    return sink.count
