"""Kanovsky's operator loop over the camera swarm, as a library object the console's page is a view of.

The operator of Kanovsky's simulation (§4.1) sees the ground truth, takes control of any robot
(forward, backward, rotate in place), and commands it to *take a picture* (which robots are in its
view cone), to *report* what it knows to the swarm over the network, and to *read* the network and
localize. :class:`OperatorSwarm` runs that loop over the project's swarm (:mod:`sims.simulation.swarm`): the true
world, each robot's on-board EKF agent and the simulated radio, advanced one step per :meth:`tick`.

Within a step the robots work as in :class:`sims.simulation.swarm.SwarmSim` (phase A: odometry and detections;
phase B: estimates), but gated by the operator's commands: a robot's camera is read only at a step
where it takes a picture, its detections and estimates go on the radio only when it reports, and what
arrives for it is held in its inbox, unread, until it is told to read (the paper's "received and
processed immediately, but not acted on until the operator gives more instructions"). Odometry is
the exception: every robot broadcasts its encoders (its peers' tracks follow its motion) every other
step, and at every step where the operator commands anyone.
A report read later than the step it was made is used only while neither its sender, its reader nor
(for an estimate) its subject has moved since, as far as the reader knows from odometry; otherwise it
is discarded as stale and counted. With ``auto`` every robot does all three every step: the swarm's
own loop.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, replace

import numpy as np

from decentral.errors import InputError
from decentral.geometry import rot2, wrap_angle
from protocols.messages import BROADCAST, OdometryReport, PoseEstimates, Tracks
from sims.console.radio import BatchedRadio
from sims.simulation.swarm.config import SwarmConfig
from sims.simulation.swarm.robot import SHARE_MAX_STD, SwarmRobot
from sims.simulation.swarm.sim import SwarmSim
from sims.simulation.swarm.world import wander_actions

__all__ = ["DRIVE_ACTIONS", "OperatorSwarm", "TickRecord"]

#: operator's drive commands: (speed fraction, yaw-rate fraction) of the robot's limits
DRIVE_ACTIONS = {"forward": (1.0, 0.0), "backward": (-1.0, 0.0), "left": (0.0, 1.0), "right": (0.0, -1.0),
                 "stop": (0.0, 0.0)}
#: a drive command holds for this long [s] unless renewed (a held key renews it)
DRIVE_HOLD = 0.5
#: odometry below this many floor-noise standard deviations counts as standing still
STILL_SIGMAS = 4.0
#: steps between two odometry broadcasts while nobody is commanded (at most ODOMETRY_HISTORY - 2)
ODOMETRY_EVERY = 2
#: steps over which a link's recent loss is measured
LOSS_WINDOW = 25


@dataclass(frozen=True)
class TickRecord:
    """Figures of one step, for the error and traffic panels.

    Attributes
    ----------
    k : int
    t : float
    error : ndarray, shape (n,)
        Per observer, the mean position error [m] of its estimates of the others against truth
        (NaN where it tracks nobody: there is no error to show, never a made-up zero).
    tracked : ndarray, shape (n,)
        Per observer, how many robots it tracks.
    messages, bytes : int
        Radio totals (sent) so far.
    """

    k: int
    t: float
    error: np.ndarray
    tracked: np.ndarray
    messages: int
    bytes: int


class OperatorSwarm:
    """The swarm under an operator: drive, take pictures, report, read and localize.

    Parameters
    ----------
    config : SwarmConfig
    seed : int
        Entry point of all randomness (as :class:`sims.simulation.swarm.SwarmSim`).
    auto : bool
        Every robot takes a picture, reports and reads every step, and the robots the operator is
        not driving wander (the swarm's own loop); otherwise only what the operator commands happens
        and undriven robots stand still.
    history : int
        Steps kept for the panels.

    Examples
    --------
    >>> from sims.simulation.swarm import SwarmConfig
    >>> op = OperatorSwarm(SwarmConfig(n_robots=3), seed=1)
    >>> op.drive("R0", "forward"); op.tick().k
    1
    >>> sorted(op.picture("R1")) == sorted(op.in_view("R1"))
    True
    """

    def __init__(self, config: SwarmConfig, seed: int, *, auto: bool = False, history: int = 600):
        self.config = config
        self.seed = int(seed)
        self.auto = bool(auto)
        self.sim = SwarmSim(config, seed)
        self.names = config.names
        self.index = {n: i for i, n in enumerate(self.names)}
        self.k = -1
        self.t = 0.0
        self._drive: dict[str, tuple[float, float, float]] = {}  # name -> (v, omega, until t)
        self._picture: set[str] = set()
        self._report: set[str] = set()
        self._read: set[str] = set()
        self.inbox: dict[str, list] = {n: [] for n in self.names}
        self.last_picture: dict[str, Tracks] = {}
        self.seen: dict[str, tuple[str, ...]] = {}  # robot -> robots its last picture identified
        self.detections: dict[str, tuple] = {}  # robot -> its picture's detections, this step only
        self.stale_discarded = 0
        # reader -> sender -> last round the reader knows the sender moved (from odometry)
        self._moved = {n: {} for n in self.names}
        self._move_cache: dict[tuple[str, int], int] = {}
        self._stats = None
        self.sent_copies = 0  # copies put on the radio (a broadcast is one per receiver), and their bytes
        self.sent_bytes = 0
        n = len(self.names)
        self._sent = deque(maxlen=LOSS_WINDOW)  # per step: (n, n) copies sent / delivered
        self._delivered = deque(maxlen=LOSS_WINDOW)
        self.history: deque[TickRecord] = deque(maxlen=history)
        self._n = n
        self._radio = BatchedRadio(self.sim.network, self.names)
        self.tick()  # step 0: robots at their start poses, nothing moved yet

    # ------------------------------------------------------------------ operator commands
    def _check(self, name: str) -> None:
        if name not in self.index:
            raise InputError(f"no robot {name!r} (robots: {self.names[0]}..{self.names[-1]})", field="robot")

    def drive(self, name: str, action: str) -> None:
        """Drive robot ``name`` (``forward``, ``backward``, ``left``, ``right``: rotate in place, ``stop``)
        for the next :data:`DRIVE_HOLD` seconds of simulated time."""
        self._check(name)
        if action not in DRIVE_ACTIONS:
            raise InputError(f"unknown drive command {action!r} (one of {', '.join(DRIVE_ACTIONS)})", field="action")
        fv, fw = DRIVE_ACTIONS[action]
        c = self.config
        self._drive[name] = (fv * c.max_speed, fw * c.max_yaw_rate, self.t + DRIVE_HOLD)

    def in_view(self, name: str) -> tuple[str, ...]:
        """Robots truly inside ``name``'s view cone now (the operator's ground truth, Kanovsky §3.1)."""
        self._check(name)
        return self.sim.world.sense(None).visible[name]

    def picture(self, name: str) -> tuple[str, ...]:
        """Robot ``name`` takes a picture at the next step; returns the robots now in its view cone
        (what the picture will identify, less tag drop-outs)."""
        self._check(name)
        self._picture.add(name)
        return self.in_view(name)

    def report(self, name: str) -> None:
        """Robot ``name`` sends what it knows to the swarm at the next step."""
        self._check(name)
        self._report.add(name)

    def read(self, name: str) -> None:
        """Robot ``name`` reads the network and localizes at the next step."""
        self._check(name)
        self._read.add(name)

    def loop_all(self) -> None:
        """Every robot takes a picture, reports and reads at the next step: one turn of the loop for the
        whole swarm at one instant (the EKF's yaw comes from two robots seeing each other at once)."""
        self._picture.update(self.names)
        self._report.update(self.names)
        self._read.update(self.names)

    def command(self, name: str, what: str) -> None:
        """One operator command by name: a drive action, ``picture``, ``report`` or ``read``."""
        if what in DRIVE_ACTIONS:
            self.drive(name, what)
        elif what in ("picture", "report", "read"):
            getattr(self, what)(name)
        else:
            raise InputError(f"unknown command {what!r}", field="command")

    # ------------------------------------------------------------------ one step
    def _actions(self) -> np.ndarray:
        out = wander_actions(self.sim.world) if self.auto else np.zeros((self._n, 2))
        for name, (v, w, until) in list(self._drive.items()):
            if self.t < until - 1e-9:
                out[self.index[name]] = (v, w)
            else:
                del self._drive[name]
        return out

    def _still(self, motion: np.ndarray) -> bool:
        c = self.config
        return (math.hypot(motion[0], motion[1]) < STILL_SIGMAS * c.odom_floor * math.sqrt(2)
                and abs(motion[2]) < STILL_SIGMAS * c.yaw_floor)

    def _last_move(self, m: OdometryReport) -> int:
        """Last round in which the report's sender moved (-1: none in the report); computed once per report."""
        key = (m.sender, m.round)
        if key not in self._move_cache:
            rows = [row for row, w in enumerate(m.motions) if not self._still(w)]
            self._move_cache[key] = m.first_round + rows[-1] if rows else -1
        return self._move_cache[key]

    def _note_motion(self, reader: str, deliveries) -> None:
        moved = self._moved[reader]
        for d in deliveries:
            r = self._last_move(d.message)
            if r > moved.get(d.message.sender, -1):
                moved[d.message.sender] = r

    def _usable(self, reader: str, msg, k: int):
        """The held message restamped to round ``k``, or ``None`` when someone involved has moved since."""
        if msg.round == k:
            return msg
        moved = self._moved[reader]
        if moved.get(reader, -1) > msg.round or moved.get(msg.sender, -1) > msg.round:
            return None
        if isinstance(msg, PoseEstimates):
            keep = [i for i, s in enumerate(msg.subjects) if moved.get(s, -1) <= msg.round]
            self.stale_discarded += len(msg.subjects) - len(keep)  # estimates of robots that moved since
            if not keep:
                return None
            msg = replace(msg, subjects=tuple(msg.subjects[i] for i in keep), poses=msg.poses[keep],
                          covariances=msg.covariances[keep])
        return replace(msg, round=k)

    def _route(self, name: str, robot: SwarmRobot, deliveries, reading: bool, k: int, delivered: np.ndarray) -> None:
        j = self.index[name]
        for d in deliveries:
            delivered[self.index[d.message.sender], j] += 1
        own = [d for d in deliveries if isinstance(d.message, OdometryReport)]
        self._note_motion(name, own)
        robot.receive(own)
        self.inbox[name].extend(d.message for d in deliveries if not isinstance(d.message, OdometryReport))
        if reading:
            use = []
            for msg in self.inbox[name]:
                kept = self._usable(name, msg, k)
                if kept is None:
                    self.stale_discarded += 1
                else:
                    use.append(kept)
            self.inbox[name] = [m for m in self.inbox[name] if m.round > k]  # none, unless from the future
            robot.receive(use)

    def _send(self, msgs, now: float, sent: np.ndarray) -> None:
        copies, size = self._radio.send(msgs, now, sent)
        # the radio's own totals need a full snapshot of its books (every link): keep ours as we go
        self.sent_copies += copies
        self.sent_bytes += size

    def _report_estimates(self, robot: SwarmRobot, k: int, t: float) -> PoseEstimates:
        """What ``robot`` knows of the others from its own camera (and mutual views), in its frame now."""
        subjects, poses, covs = [], [], []
        for name, tr in robot.estimates().items():
            if tr.source != "peer" and math.sqrt(max(tr.cov[0, 0], tr.cov[1, 1])) < SHARE_MAX_STD:
                subjects.append(name)
                poses.append(tr.mean)
                covs.append(tr.cov)
        return PoseEstimates(sender=robot.name, receiver=BROADCAST, round=k, t=t, subjects=tuple(subjects),
                             poses=np.array(poses).reshape(-1, 3), covariances=np.array(covs).reshape(-1, 3, 3))

    def tick(self) -> TickRecord:
        """Advance one step: move, then the two radio phases gated by the operator's commands."""
        c, sim = self.config, self.sim
        world, net, robots = sim.world, sim.network, sim.robots
        motion = world.step(self._actions()) if self.k >= 0 else None
        self.k += 1
        k = self.k
        self.t = t = k * c.dt
        sensing = world.sense(motion)
        everyone = set(self.names)
        pictures = everyone if self.auto else self._picture
        reports = everyone if self.auto else self._report
        reads = everyone if self.auto else self._read
        self._picture, self._report, self._read = set(), set(), set()
        self._move_cache.clear()
        n = self._n
        sent, delivered = np.zeros((n, n), np.int64), np.zeros((n, n), np.int64)
        # encoders go on the radio every ODOMETRY_EVERY steps (each report repeats the last four steps'
        # motions, so nothing is lost), and at every step where a robot pictures, reports or reads, so
        # that every track is brought to the present before it is measured, shared or fused
        odometry_now = self.auto or k % ODOMETRY_EVERY == 0 or bool(pictures or reports or reads)
        # phase A: odometry (always) and, for reporting robots, their latest picture's detections
        self.detections = {}
        out = []
        for name, robot in robots.items():
            dets = sensing.detections[f"{name}/cam0"] if name in pictures else ()
            if name in pictures:
                self.seen[name] = tuple(self.names[d.node] for d in dets)
                self.detections[name] = dets
            own = sensing.odometry.get(name)
            if own is not None:
                u = np.array([own.dp[0], own.dp[1], own.dtheta])
                if not self._still(u):
                    self._moved[name][name] = k
            for msg in robot.sense(k, t, own, dets):
                if isinstance(msg, Tracks):
                    if name in pictures:
                        self.last_picture[name] = msg
                    if name in reports and name in self.last_picture:
                        out.append(self.last_picture[name])
                elif odometry_now:
                    out.append(msg)
        self._send(out, t, sent)
        t_a = t + c.deadline * c.dt
        arrived = self._radio.poll(t_a)
        for name, robot in robots.items():
            self._route(name, robot, arrived[name], name in reads, k, delivered)
            robot.update()
        # phase B: estimates of reporting robots; reading robots fuse what they hold
        t_b = t + 0.5 * c.dt
        out = []
        for name in sorted(reports):
            robot = robots[name]
            out += robot.share() if self.auto else [self._report_estimates(robot, k, t)]
        self._send(out, t_b, sent)
        t_b_end = t_b + c.deadline * c.dt
        arrived = self._radio.poll(t_b_end)
        for name, robot in robots.items():
            self._route(name, robot, arrived[name], name in reads, k, delivered)
            robot.fuse()
        self._sent.append(sent)
        self._delivered.append(delivered)
        rec = self._record()
        self.history.append(rec)
        return rec

    # ------------------------------------------------------------------ read-out (truth is the operator's)
    def truth(self) -> np.ndarray:
        """True ``(x, y, theta)`` of every robot in the world frame, shape (n, 3)."""
        return self.sim.world.state.copy()

    def estimates_of(self, observer: str) -> dict[str, dict]:
        """Observer's estimates of the others, drawn from its true pose into the world frame.

        Returns
        -------
        dict
            Target -> ``{"x", "y", "theta", "cov": (2, 2) world-frame position covariance,
            "yaw_known", "source", "error"}`` (``error``: position error [m] against truth).
        """
        self._check(observer)
        i = self.index[observer]
        state = self.sim.world.state
        Ri = rot2(state[i, 2])
        out = {}
        for name, tr in self.sim.robots[observer].estimates().items():
            xy = state[i, :2] + Ri @ tr.mean[:2]
            cov = Ri @ tr.cov[:2, :2] @ Ri.T
            j = self.index[name]
            out[name] = {"x": float(xy[0]), "y": float(xy[1]), "theta": float(wrap_angle(state[i, 2] + tr.mean[2])),
                         "cov": cov, "yaw_known": tr.yaw_known, "source": tr.source,
                         "error": float(np.hypot(*(xy - state[j, :2])))}
        return out

    def link_loss(self) -> np.ndarray:
        """Recent loss per directed link (sender, receiver), shape (n, n); NaN where nothing was sent."""
        sent = np.sum(self._sent, axis=0) if self._sent else np.zeros((self._n, self._n))
        got = np.sum(self._delivered, axis=0) if self._delivered else np.zeros((self._n, self._n))
        with np.errstate(invalid="ignore", divide="ignore"):
            loss = np.where(sent > 0, 1.0 - got / np.maximum(sent, 1), np.nan)
        return np.clip(loss, 0.0, 1.0, where=np.isfinite(loss), out=loss)

    def _record(self) -> TickRecord:
        n = self._n
        err = np.full(n, np.nan)
        tracked = np.zeros(n, dtype=np.int64)
        state = self.sim.world.state
        for i, name in enumerate(self.names):
            robot = self.sim.robots[name]
            if not robot.tracks:
                continue
            Ri = rot2(state[i, 2])
            e = []
            for target, tr in robot.tracks.items():
                j = self.index[target]
                true = Ri.T @ (state[j, :2] - state[i, :2])
                e.append(math.hypot(*(true - tr.mean[:2])))
            err[i], tracked[i] = float(np.mean(e)), len(e)
        return TickRecord(self.k, self.t, err, tracked, self.sent_copies, self.sent_bytes)

    def network_stats(self):
        """The radio's counters (:class:`protocols.transport.TransportStats`) at this step (computed once per step)."""
        if self._stats is None or self._stats[0] != self.k:
            self._stats = (self.k, self.sim.network.stats())
        return self._stats[1]

    def counters(self) -> dict:
        """Radio counters (sent, delivered, dropped, bytes) in total and per robot, and stale reports."""
        s = self.network_stats()
        return {"total": s.total.as_dict(),
                "per_robot": {n: s.per_sender[n].as_dict() for n in self.names if n in s.per_sender},
                "stale_discarded": self.stale_discarded,
                "unread": {n: len(v) for n, v in self.inbox.items()}}
