"""FreeSN-like assemblies driven online, each with an :class:`agents.assembly.AssemblyAgent`.

The shapes, cameras and start poses come from a registered scenario of :mod:`sims.simulation.scenarios`
(``"multi"`` by default: a ring of assemblies, each camera aimed at the next); from then on the
roots move as unicycles under the env's commands, and every step

1. the sensors of :mod:`sims.simulation.world.sensors` give each assembly its odometry and detections (the
   scenario's noise model and per-source streams);
2. each live agent takes its own data (:meth:`AssemblyAgent.on_step`), and ``admm_rounds`` rounds of
   consensus-ADMM run over the simulated lossy network, two phases per round, all inside the step;
3. each agent's estimates (poses of the assemblies it can place, in its root frame, Liu et al. 2024
   eq. (19)) are compared with the truth for the env's ``infos``.

A crashed agent is skipped while down and restarts empty when it comes back (as in
:func:`sims.runners.admm_run.run_admm`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from agents.assembly import AgentConfig, AssemblyAgent, OwnStep
from decentral.admm import AdmmConfig
from decentral.filtering import compose
from decentral.geometry import wrap_angle
from decentral.observations import Step
from protocols.network import LinkConfig, NetworkConfig, SimulatedNetwork
from sims.simulation.scenarios import get_scenario
from sims.simulation.swarm.world import streams_for, unicycle_step
from sims.simulation.world.sensors import detections_at, odometry_at, sensor_streams
from sims.simulation.world.world import AssemblyTrack, World

__all__ = ["AssemblySimConfig", "AssemblyReport", "AssemblySim"]


@dataclass(frozen=True)
class AssemblySimConfig:
    """Parameters of the assemblies scenario of the env.

    Attributes
    ----------
    source : str
        Registered scenario providing shapes, cameras and start poses.
    n_assemblies : int
    dt : float
        Step [s].
    admm_rounds : int
        ADMM rounds run per step.
    window : int
        Sliding-window length K of the agents.
    max_speed, max_yaw_rate : float
        Limits of the unicycle commands of each root [m/s], [rad/s].
    link : LinkConfig
        Radio behaviour.
    """

    source: str = "multi"
    n_assemblies: int = 4
    dt: float = 0.2
    admm_rounds: int = 10
    window: int = 5
    max_speed: float = 0.1
    max_yaw_rate: float = 0.3
    link: LinkConfig = LinkConfig(latency=0.0005, jitter=0.001)

    def __post_init__(self) -> None:
        from decentral.errors import InputError

        if not (isinstance(self.n_assemblies, int) and self.n_assemblies >= 2):
            raise InputError("must be an integer >= 2", field="n_assemblies")
        if not (isinstance(self.admm_rounds, int) and self.admm_rounds >= 1):
            raise InputError("must be an integer >= 1", field="admm_rounds")
        for name in ("dt", "max_speed", "max_yaw_rate"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise InputError("must be positive", field=name)


@dataclass(frozen=True)
class AssemblyReport:
    """One step: truth, the log step, and every agent's estimates and their errors."""

    k: int
    t: float
    step: Step
    state: np.ndarray
    estimates: dict
    errors: dict
    converged: dict


class AssemblySim:
    """Assemblies and their agents, stepped online (see the module docstring)."""

    def __init__(self, config: AssemblySimConfig, seed: int, *, crashes: tuple = (), partitions: tuple = ()):
        self.config = c = config
        scen = get_scenario(c.source, n_assemblies=c.n_assemblies, steps=1, dt=c.dt)
        world0 = scen.make_world(np.random.default_rng(np.random.SeedSequence(seed).spawn(1)[0]))
        self.node_radius = world0.node_radius
        self.names = tuple(a.name for a in world0.assemblies)
        self.tracks0 = {a.name: a for a in world0.assemblies}
        self.cameras = tuple(replace(rig, mounts=()) for rig in world0.cameras)
        self.state = np.array([[a.xy[0, 0], a.xy[0, 1], a.yaw[0]] for a in world0.assemblies])
        self.noise = scen.config.sensor_model
        self.streams = sensor_streams(seed, [f"odometry/{n}" for n in self.names] + [r.key for r in self.cameras])
        net_seed = int(streams_for(seed, ["network"])["network"].integers(2**63))
        self.network = SimulatedNetwork(
            NetworkConfig(agents=self.names, link=c.link, crashes=tuple(crashes), partitions=tuple(partitions),
                          round_period=c.dt / max(c.admm_rounds, 1)),
            np.random.default_rng(net_seed),
        )
        self.agents = {n: self._new_agent(n) for n in self.names}
        self._was_down = {n: False for n in self.names}
        self.own_pose = {n: np.zeros(3) for n in self.names}
        self.k = -1
        self._prev = self.state.copy()
        self.last_heard: dict[str, set[str]] = {n: set() for n in self.names}

    def _new_agent(self, name: str) -> AssemblyAgent:
        cams = tuple(rig.as_camera() for rig in self.cameras if rig.assembly == name)
        return AssemblyAgent(AgentConfig(name=name, assemblies=self.names, reference=self.names[0], cameras=cams,
                                         node_radius=self.node_radius, window=self.config.window,
                                         admm=AdmmConfig()))

    def world(self, states: list[np.ndarray], t: float) -> World:
        """A World holding the given consecutive root states (one or two steps)."""
        times = np.array([t - self.config.dt * (len(states) - 1 - i) for i in range(len(states))])
        tracks = []
        for i, n in enumerate(self.names):
            a = self.tracks0[n]
            xy = np.array([s[i, :2] for s in states])
            yaw = np.array([s[i, 2] for s in states])
            tracks.append(AssemblyTrack(n, a.floor_z, xy, yaw, (a.shapes[0],) * len(states)))
        return World(self.node_radius, times, tuple(tracks), self.cameras)

    def relative(self, i: int, j: int) -> tuple[np.ndarray, float]:
        """True position (3,) of j's root in i's root frame and relative yaw (Liu et al. 2024 eq. (19))."""
        w = self.world([self.state], self.k * self.config.dt)
        Pi, Pj = w.assemblies[i].root_pose(0, self.node_radius), w.assemblies[j].root_pose(0, self.node_radius)
        return Pi.R.T @ (Pj.p - Pi.p), float(wrap_angle(self.state[j, 2] - self.state[i, 2]))

    def step(self, actions: np.ndarray | None = None) -> AssemblyReport:
        c = self.config
        if self.k >= 0:
            a = np.zeros((len(self.names), 2)) if actions is None else np.asarray(actions, float)
            v = np.clip(a[:, 0], -c.max_speed, c.max_speed)
            w = np.clip(a[:, 1], -c.max_yaw_rate, c.max_yaw_rate)
            self._prev = self.state.copy()
            self.state = unicycle_step(self.state, v, w, c.dt)
        self.k += 1
        k, t = self.k, self.k * c.dt
        world = self.world([self._prev, self.state] if k > 0 else [self.state], t)
        idx = world.steps - 1
        detections, _ = detections_at(world, idx, self.noise, self.streams)
        odometry = {}
        if k > 0:
            for n in self.names:
                odo = odometry_at(world, n, idx, self.noise, self.streams[f"odometry/{n}"])
                if odo is not None:
                    odometry[n] = odo
                    self.own_pose[n] = compose(self.own_pose[n], np.array([odo.dp[0], odo.dp[1], odo.dtheta]))
        config = {n: self.tracks0[n].shapes[0].as_config() for n in self.names}
        step = Step(t, config, odometry, detections)
        net = self.network
        heard = {n: set() for n in self.names}
        for n in self.names:
            down = net.is_down(n, t)
            if self._was_down[n] and not down:
                self.agents[n] = self._new_agent(n)  # restarts empty and catches up from its peers
            self._was_down[n] = down
            if down:
                continue
            prefix = n + "/"
            self.agents[n].on_step(OwnStep(step=k, t=t, config=config[n], odometry=odometry.get(n),
                                           detections={key: d for key, d in detections.items() if key.startswith(prefix)}))
            for m in self.agents[n].outbox():
                net.send(m, t)
        halves = 2 * max(c.admm_rounds, 1)
        for h in range(halves):
            th = t + (h + 1) * c.dt / (halves + 1)
            for n in self.names:
                if net.is_down(n, th):
                    continue
                agent = self.agents[n]
                for delivery in net.poll(n, th):
                    heard[n].add(delivery.sender)
                    agent.handle(delivery.message)
                agent.tick(k * c.admm_rounds + h // 2)
                for m in agent.outbox():
                    net.send(m, th)
        self.last_heard = heard
        estimates, errors, converged = {}, {}, {}
        for i, n in enumerate(self.names):
            est = self.agents[n].estimates()
            estimates[n] = est
            converged[n] = bool(self.agents[n].converged)
            row = {}
            for m, pose in est.items():
                j = self.names.index(m)
                p, th = self.relative(i, j)
                row[m] = (float(np.linalg.norm(np.asarray(pose.p) - p)), float(abs(wrap_angle(pose.theta - th))))
            errors[n] = row
        return AssemblyReport(k, t, step, self.state.copy(), estimates, errors, converged)
