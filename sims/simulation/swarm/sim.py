"""Kanovsky's swarm, end to end: true world, on-board robots, and the simulated radio between them.

:class:`SwarmSim` advances everything by one step per call (the PettingZoo env drives it);
:func:`run_swarm` runs a whole episode with the built-in wander policy and returns a
:class:`SwarmRun`: the observation log in the contract's in-memory form (one-node assemblies, each
with a camera, so the project's estimators apply unchanged), the truth, each robot's estimates and
their errors, and the network's counters.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from decentral.filtering import compose, invert, nees
from decentral.geometry import rotz, wrap_angle
from decentral.metrics import GroundTruth
from decentral.observations import ObservationLog, Step
from protocols.network import Crash, NetworkConfig, Partition, SimulatedNetwork
from protocols.transport import TransportStats
from sims.simulation.swarm.config import SwarmConfig
from sims.simulation.swarm.robot import SwarmRobot
from sims.simulation.swarm.world import Sensing, SwarmWorld, streams_for, wander_actions

__all__ = ["PairError", "StepReport", "SwarmSim", "SwarmRun", "run_swarm"]


@dataclass(frozen=True)
class PairError:
    """Error of observer's estimate of target against truth (evaluation only).

    ``position`` [m]; ``yaw`` [rad] only when the observer considers the yaw known; ``nees`` of the
    (x, y, theta) error when the yaw is known, else of (x, y); ``dof`` its degrees of freedom.
    """

    position: float
    yaw: float | None
    nees: float
    dof: int


@dataclass(frozen=True)
class StepReport:
    """One step of a swarm run.

    Attributes
    ----------
    k : int
    t : float
    step : decentral.observations.Step
        The log step (config, odometry, detections).
    state : ndarray, shape (n, 3)
        True ``(x, y, theta)`` of every robot in W.
    sensing : Sensing
    errors : dict[str, dict[str, PairError]]
        Observer -> target -> error of the observer's current estimate.
    own_pose_error : dict[str, float]
        Observer -> position error [m] of its own dead-reckoned pose in its start frame.
    """

    k: int
    t: float
    step: Step
    state: np.ndarray
    sensing: Sensing
    errors: dict
    own_pose_error: dict


class SwarmSim:
    """A swarm episode stepped one step at a time.

    Parameters
    ----------
    config : SwarmConfig
    seed : int
        Entry point of all randomness (world, sensors, policy, radio each get their own streams).
    partitions, crashes : tuple
        Faults of the radio (see :mod:`protocols.network`).
    """

    def __init__(self, config: SwarmConfig, seed: int, *, partitions: tuple[Partition, ...] = (),
                 crashes: tuple[Crash, ...] = ()):
        self.config = config
        self.seed = int(seed)
        self.world = SwarmWorld(config, seed)
        self.start = self.world.state.copy()
        net_rng = np.random.default_rng(streams_for(seed, ["network"])["network"].integers(2**63))
        self.network = SimulatedNetwork(
            NetworkConfig(agents=config.names, link=config.link, round_period=config.dt,
                          partitions=tuple(partitions), crashes=tuple(crashes)),
            net_rng,
        )
        self.robots = {n: SwarmRobot(n, config) for n in config.names}
        self.k = -1
        self._motion: np.ndarray | None = None

    def step(self, actions: np.ndarray | None = None) -> StepReport:
        """Advance one step: move (not before step 0), sense, run both radio phases, evaluate.

        Parameters
        ----------
        actions : ndarray, shape (n, 2), optional
            ``(v, omega)`` per robot; ``None`` uses the wander policy.
        """
        c = self.config
        if self.k >= 0:
            if actions is None:
                actions = wander_actions(self.world)
            self._motion = self.world.step(actions)
        self.k += 1
        k, t = self.k, self.k * c.dt
        sensing = self.world.sense(self._motion if k > 0 else None)
        net = self.network
        # phase A: odometry and detections
        for n, robot in self.robots.items():
            for msg in robot.sense(k, t, sensing.odometry.get(n), sensing.detections[f"{n}/cam0"]):
                net.send(msg, t)
        t_a = t + c.deadline * c.dt
        for n, robot in self.robots.items():
            robot.receive(net.poll(n, t_a))
            robot.update()
        # phase B: estimates
        t_b = t + 0.5 * c.dt
        for n, robot in self.robots.items():
            for msg in robot.share():
                net.send(msg, t_b)
        t_b_end = t_b + c.deadline * c.dt
        for n, robot in self.robots.items():
            robot.receive(net.poll(n, t_b_end))
            robot.fuse()
        log_step = Step(
            t,
            {n: {i: np.zeros(3)} for i, n in enumerate(c.names)},
            dict(sensing.odometry),
            dict(sensing.detections),
        )
        return StepReport(k, t, log_step, self.world.state.copy(), sensing, self._errors(), self._own_errors())

    def _errors(self) -> dict:
        out = {}
        for i, obs in enumerate(self.config.names):
            robot = self.robots[obs]
            row = {}
            for name, tr in robot.estimates().items():
                j = self.config.names.index(name)
                true = self.world.relative(i, j)
                e = true - tr.mean
                e[2] = wrap_angle(e[2])
                pos = float(np.hypot(e[0], e[1]))
                if tr.yaw_known:
                    row[name] = PairError(pos, float(abs(e[2])), nees(e, tr.cov), 3)
                else:
                    row[name] = PairError(pos, None, float(e[:2] @ np.linalg.solve(tr.cov[:2, :2], e[:2])), 2)
            out[obs] = row
        return out

    def _own_errors(self) -> dict:
        out = {}
        for i, n in enumerate(self.config.names):
            true = compose(invert(self.start[i]), self.world.state[i])
            out[n] = float(np.hypot(*(true[:2] - self.robots[n].pose[:2])))
        return out


@dataclass(frozen=True)
class SwarmRun:
    """A whole swarm episode.

    Attributes
    ----------
    config : SwarmConfig
    seed : int
    log : ObservationLog
        Contract ``decentral.log/1`` in memory: robots ``R0..`` with one node (id ``i``) and one camera.
    truth : GroundTruth
        True root poses in W at every step.
    reports : tuple[StepReport, ...]
    network : TransportStats
    robot_stats : dict[str, dict]
    """

    config: SwarmConfig
    seed: int
    log: ObservationLog
    truth: GroundTruth
    reports: tuple
    network: TransportStats
    robot_stats: dict = field(default_factory=dict)

    def summary(self) -> dict:
        """JSON-ready figures: mean errors, tracked fraction, mean NEES per dof, messages."""
        n = self.config.n_robots
        pos, yaw, nees3, nees2, tracked, yaw_frac = [], [], [], [], [], []
        for rep in self.reports:
            pairs = [e for row in rep.errors.values() for e in row.values()]
            tracked.append(len(pairs) / max(n * (n - 1), 1))
            yaw_frac.append(sum(e.yaw is not None for e in pairs) / max(n * (n - 1), 1))
            pos += [e.position for e in pairs]
            yaw += [e.yaw for e in pairs if e.yaw is not None]
            nees3 += [e.nees for e in pairs if e.dof == 3]
            nees2 += [e.nees for e in pairs if e.dof == 2]
        med = lambda v: float(np.median(v)) if v else None
        mean = lambda v: float(np.mean(v)) if v else None
        return {
            "steps": len(self.reports),
            "robots": n,
            "tracked_fraction_final": tracked[-1] if tracked else 0.0,
            "yaw_known_fraction_final": yaw_frac[-1] if yaw_frac else 0.0,
            "position_error_median_m": med(pos),
            "position_error_mean_m": mean(pos),
            "yaw_error_median_deg": None if not yaw else float(np.degrees(np.median(yaw))),
            "nees3_mean": mean(nees3),
            "nees3_median": med(nees3),
            "nees2_mean": mean(nees2),
            "own_pose_error_final_m": mean(list(self.reports[-1].own_pose_error.values())) if self.reports else None,
            "messages_sent": self.network.total.sent,
            "messages_delivered": self.network.total.delivered,
            "bytes_sent": self.network.total.bytes_sent,
        }


def run_swarm(config: SwarmConfig = SwarmConfig(), seed: int = 0, steps: int = 100, *,
              partitions: tuple = (), crashes: tuple = ()) -> SwarmRun:
    """Run ``steps`` steps of the swarm with the wander policy and collect everything."""
    sim = SwarmSim(config, seed, partitions=partitions, crashes=crashes)
    reports = tuple(sim.step() for _ in range(steps))
    names = config.names
    log = ObservationLog(
        node_radius=config.node_radius,
        assemblies=names,
        cameras={f"{n}/cam0": config.camera(n) for n in names},
        steps=tuple(r.step for r in reports),
    )
    times = np.array([r.t for r in reports])
    states = np.stack([r.state for r in reports])  # (T, n, 3)
    R = {n: rotz(states[:, i, 2]) for i, n in enumerate(names)}
    p = {n: np.column_stack([states[:, i, :2], np.full(len(times), config.node_radius)]) for i, n in enumerate(names)}
    truth = GroundTruth(times, R, p)
    robot_stats = {n: vars(r.stats).copy() for n, r in sim.robots.items()}
    return SwarmRun(config, int(seed), log, truth, reports, sim.network.stats(), robot_stats)
