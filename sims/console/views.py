"""What each of the console's sources shows, as data: the swarm's top view, a finished run's replay and
a launch's agents. The web page (:mod:`sims.console.app`) only draws these."""

from __future__ import annotations

import math

import numpy as np

from sims.console.scene import Body, Cone, Frame, Link, Mark
from sims.console.streams import StreamFollower, record_pose

__all__ = ["swarm_frame", "error_series", "Replay", "launch_rows", "launch_series"]

#: up to this many robots the error panel has a line per robot; beyond, the selected one and the median
PER_ROBOT_LINES = 12


def swarm_frame(op, selected: str | None, mode: str = "by", links: str = "selected") -> Frame:
    """The swarm's top view in the world frame.

    Parameters
    ----------
    op : sims.console.operator.OperatorSwarm
    selected : str, optional
        The robot under the operator's control (its cone and links are highlighted).
    mode : {"by", "of", "all"}
        Estimates shown: the selected robot's of the others, everyone's of the selected robot, or all.
    links : {"selected", "all", "none"}
        Radio links drawn, coloured by recent loss.
    """
    c = op.config
    state = op.truth()
    cam = c.cam_in_root().p
    bodies, cones = [], []
    for i, name in enumerate(op.names):
        x, y, th = state[i]
        bodies.append(Body(name, float(x), float(y), float(th), c.node_radius))
        ax = x + math.cos(th) * cam[0] - math.sin(th) * cam[1]
        ay = y + math.sin(th) * cam[0] + math.cos(th) * cam[1]
        cones.append(Cone(name, float(ax), float(ay), float(th), math.radians(c.max_angle_deg), c.max_distance,
                          name == selected))
    if selected is not None and len(op.names) > 12:
        cones = [cn for cn in cones if cn.selected]  # a crowd of cones hides the robots
    marks = []
    observers = op.names if mode in ("of", "all") or selected is None else (selected,)
    for obs in observers:
        for target, e in op.estimates_of(obs).items():
            if mode == "of" and selected is not None and target != selected:
                continue
            marks.append(Mark(obs, target, e["x"], e["y"], e["theta"] if e["yaw_known"] else None, e["cov"],
                              e["source"], e["error"]))
    out_links = []
    if links != "none":
        loss = op.link_loss()
        n = len(op.names)
        for i in range(n):
            for j in range(i + 1, n):
                a, b = op.names[i], op.names[j]
                if links == "selected" and selected not in (a, b):
                    continue
                pair = [v for v in (loss[i, j], loss[j, i]) if math.isfinite(v)]
                out_links.append(Link(a, b, max(pair) if pair else None))
    a = c.arena
    label = f"step {op.k}  t = {op.t:.1f} s" + ("  (auto)" if op.auto else "")
    return Frame((0.0, 0.0, a, a), tuple(bodies), tuple(marks), tuple(cones), tuple(out_links), selected, (), label)


def error_series(op, selected: str, per_robot: int = PER_ROBOT_LINES) -> dict[str, list]:
    """The error panel's lines: ``name -> [[t, error_m or None], ...]`` over the kept history.

    One line per robot (its mean position error against truth over the robots it tracks; ``None``
    while it tracks nobody) when there are at most ``per_robot`` robots, else only ``selected``'s; and
    the swarm's median as ``"median"``.
    """
    hist = list(op.history)
    names = op.names if len(op.names) <= per_robot else (selected,)
    out = {n: [] for n in names}
    out["median"] = []
    for h in hist:
        t = round(h.t, 2)
        for n in names:
            e = h.error[op.index[n]]
            out[n].append([t, round(float(e), 4) if math.isfinite(e) else None])
        fin = h.error[np.isfinite(h.error)]
        out["median"].append([t, round(float(np.median(fin)), 4) if fin.size else None])
    return out


def _yaw(R: np.ndarray) -> float:
    return float(math.atan2(R[1, 0], R[0, 0]))


class Replay:
    """A finished log and its estimate (and the truth, when given) stepped with a slider.

    Everything is drawn in the reference assembly's root frame: the estimate's poses as marks (with
    the assembly's nodes from the log's configuration), the true relative poses as outlines.

    Parameters
    ----------
    log : decentral.observations.ObservationLog
    estimate : decentral.observations.Estimate
    truth : sims.simulation.world.truth.Truth, optional
    """

    def __init__(self, log, estimate, truth=None):
        from decentral.errors import InputError

        if not estimate.steps:
            raise InputError("has no steps to replay", field="steps")
        self.log, self.estimate, self.truth = log, estimate, truth
        self.reference = estimate.reference
        self.times = np.array([s.t for s in estimate.steps])
        self._log_t = np.array([s.t for s in log.steps])
        self._rel = {}
        if truth is not None:
            from decentral.metrics import relative_truth

            gt = truth.poses if hasattr(truth, "poses") else truth
            for name in gt.R:
                if name in log.assemblies and self.reference in gt.R:
                    p, th = relative_truth(gt, self.reference, name)
                    self._rel[name] = (np.asarray(gt.times), p, th)
        pts = [np.zeros(2)]
        for s in estimate.steps:
            pts += [np.asarray(pose.p[:2], float) for pose in s.poses.values()]
        for _, p, _ in self._rel.values():
            pts += list(np.asarray(p)[:, :2])
        pts = np.array(pts)
        lo, hi = pts.min(axis=0) - 0.5, pts.max(axis=0) + 0.5
        side = float(max(hi - lo))
        mid = 0.5 * (lo + hi)
        self.bounds = (float(mid[0] - side / 2), float(mid[1] - side / 2), float(mid[0] + side / 2),
                       float(mid[1] + side / 2))

    def __len__(self) -> int:
        return len(self.estimate.steps)

    def _nodes(self, name: str, k_log: int, x: float, y: float, th: float) -> tuple:
        cfg = self.log.steps[k_log].config.get(name, {}) if k_log is not None else {}
        c, s = math.cos(th), math.sin(th)
        return tuple((x + c * float(v[0]) - s * float(v[1]), y + s * float(v[0]) + c * float(v[1]))
                     for v in cfg.values())

    def frame(self, k: int) -> Frame:
        """Step ``k`` of the estimate."""
        step = self.estimate.steps[k]
        near = np.flatnonzero(np.abs(self._log_t - step.t) < 1e-6)
        k_log = int(near[0]) if len(near) else None
        r = self.log.node_radius
        bodies = [Body(self.reference, 0.0, 0.0, 0.0, r, self._nodes(self.reference, k_log, 0.0, 0.0, 0.0))]
        marks = []
        for name, pose in sorted(step.poses.items()):
            x, y, th = float(pose.p[0]), float(pose.p[1]), float(pose.theta)
            err = None
            truth = self._truth_at(name, step.t)
            if truth is not None:
                err = math.hypot(x - truth[0], y - truth[1])
            marks.append(Mark(self.reference, name, x, y, th, None, "estimate", err))
            bodies.append(Body(name, x, y, th, r, self._nodes(name, k_log, x, y, th)))
        outlines = []
        for name in self._rel:
            truth = self._truth_at(name, step.t)
            if truth is not None and name != self.reference:
                outlines.append(Body(name, truth[0], truth[1], truth[2], r))
        label = f"step {k}  t = {step.t:.2f} s  placed {len(step.poses)}/{len(self.log.assemblies) - 1}"
        return Frame(self.bounds, tuple(bodies), tuple(marks), (), (), None, tuple(outlines), label)

    def _truth_at(self, name: str, t: float):
        if name not in self._rel:
            return None
        times, p, th = self._rel[name]
        i = np.flatnonzero(np.abs(times - t) < 1e-6)
        if not len(i):
            return None
        i = int(i[0])
        return float(p[i][0]), float(p[i][1]), float(th[i])


def launch_rows(follower: StreamFollower, now: float) -> list[dict]:
    """One row per agent: its last step, rounds, whether converged, messages, bytes, rejections by
    reason, provisional steps, restarts and how long ago it last reported [s]."""
    rows = []
    for name, view in sorted(follower.agents.items()):
        rec = view.latest() or {}
        counts = view.counts()
        rows.append({
            "agent": name,
            "step": max(view.steps) if view.steps else None,
            "t": rec.get("t"),
            "rounds": rec.get("rounds"),
            "converged": rec.get("converged"),
            "status": rec.get("status"),
            "placed": len(rec["poses"]) if isinstance(rec.get("poses"), dict) else 0,
            "messages": counts["messages"],
            "bytes": counts["bytes"],
            "rejected": counts["rejected"],
            "provisional": view.provisional_steps()[-5:],
            "restarts": max(view.incarnations - 1, 0),
            "age": None if not view.last_seen else max(0.0, now - view.last_seen),
        })
    return rows


def launch_series(follower: StreamFollower, assembly: str, coord: int = 0, truth=None, reference: str | None = None
                  ) -> dict[str, list]:
    """Per agent, ``[(t, value), ...]`` of its estimate of ``assembly`` (``coord`` 0: x, 1: y, 2: theta);
    with ``truth`` (and the run's ``reference``), the true value under the key ``"truth"``."""
    out = {}
    for name, view in sorted(follower.agents.items()):
        pts = []
        for k, rec in sorted(view.steps.items()):
            pose = record_pose(rec, assembly)
            t = rec.get("t")
            if pose is not None and isinstance(t, (int, float)):
                pts.append((float(t), pose[coord]))
        out[name] = pts
    if truth is not None and reference is not None:
        from decentral.metrics import relative_truth

        gt = truth.poses if hasattr(truth, "poses") else truth
        if assembly in gt.R and reference in gt.R:
            p, th = relative_truth(gt, reference, assembly)
            vals = [float(v) for v in th] if coord == 2 else [float(v[coord]) for v in p]
            out["truth"] = list(zip((float(t) for t in gt.times), vals))
    return out
