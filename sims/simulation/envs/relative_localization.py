"""PettingZoo parallel env for decentralized relative localization.

Agents are assemblies; in the ``"swarm"`` scenario (Kanovsky) each assembly is a one-node robot with
a camera, running the on-board agent of :mod:`sims.simulation.swarm.robot` (EKF tracks of every other robot,
shared over the simulated lossy radio of :mod:`protocols.network`). The policy chooses motion
commands; the env returns what each agent really has, and puts errors against truth in ``infos``
(for evaluation only: the agents never see them).

Spaces (``n`` robots, ``m = n - 1`` peers, rows in the order of ``possible_agents`` without self):

* action: ``Box([-v_max, -w_max], [v_max, w_max])`` float32 -- forward speed [m/s], yaw rate [rad/s].
* observation: ``Dict`` of float32 boxes

  - ``detections`` (m, 4): ``seen, u, v, r`` of each peer in this step's image [px];
  - ``odometry`` (4,): ``valid, dx, dy, dtheta`` since the previous step (own root frame);
  - ``inbox`` (m, 4): from each peer this step, ``odometry heard, detections heard, estimates
    heard``, and the age in steps of the newest estimate report (capped at 100);
  - ``estimates`` (m, 8): ``tracked, yaw_known, x, y, theta, std_x, std_y, std_theta`` of each
    peer's pose in this agent's frame (zeros when not tracked);
  - ``own_pose`` (6,): ``x, y, theta, std_x, std_y, std_theta`` in the agent's start frame.

* reward: fraction of peers tracked minus the mean position error [m] of the tracked ones.
* infos: ``position_error`` / ``yaw_error`` per tracked peer, their means, ``own_pose_error``,
  and the agent's message counters.

In the ``"assemblies"`` scenario (:mod:`sims.simulation.envs.assembly_sim`) the agents are FreeSN-like
multi-node assemblies (shapes, cameras and start poses from a registered scenario, ``"multi"`` by
default) whose roots follow the commands, each running :class:`agents.assembly.AssemblyAgent`
(``admm_rounds`` rounds of consensus-ADMM per step). Its observation ``Dict`` is

  - ``detections`` (``max_detections``, 5): ``valid, node id, u, v, r`` of its cameras' detections;
  - ``odometry`` (4,): ``valid, dx, dy, dtheta``;
  - ``inbox`` (m, 3): ``heard this step, age in rounds of the newest ADMM value (<= 100), is a
    neighbour in the view graph``;
  - ``estimates`` (m, 5): ``placed, x, y, z, theta`` of each peer's root in its root frame;
  - ``converged`` (1,): the agent's consensus flag; ``own_pose`` (3,): dead-reckoned ``x, y, theta``.

Episodes end by truncation after ``max_cycles`` steps (all agents then leave ``agents``).
``render_mode="rgb_array"`` returns an OpenCV top view (truth, each agent's estimates placed through
its true pose -- so the drawn offset *is* the error --, radio links coloured by recent loss) next to
every robot's camera view.
"""

from __future__ import annotations

import functools
from dataclasses import fields, replace
from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from decentral.errors import InputError
from decentral.filtering import compose
from decentral.geometry import rot2
from protocols.network import LinkConfig
from sims.simulation.swarm.config import SwarmConfig
from sims.simulation.swarm.sim import StepReport, SwarmSim

__all__ = ["RelativeLocalizationEnv", "parallel_env", "raw_env", "SCENARIOS", "ENV_NAME"]

ENV_NAME = "relative_localization_v0"
#: scenarios this env can run
SCENARIOS = ("swarm", "assemblies")
_LINK_KEYS = {"loss": "drop", "latency": "latency", "jitter": "jitter", "duplicate": "duplicate",
              "corrupt": "corrupt", "bandwidth": "bandwidth"}
_AGE_CAP = 100.0


class RelativeLocalizationEnv(ParallelEnv):
    """Parallel env: one agent per assembly (see the module docstring for spaces and rewards).

    Parameters
    ----------
    scenario : str
        ``"swarm"`` (Kanovsky's one-node robots) or ``"assemblies"`` (FreeSN-like assemblies with
        consensus-ADMM agents; parameters are the fields of
        :class:`sims.simulation.envs.assembly_sim.AssemblySimConfig` plus ``max_detections``).
    max_cycles : int
        Steps per episode before truncation.
    render_mode : str or None
        ``"rgb_array"`` or ``None``.
    crashes, partitions : tuple
        Radio faults (:class:`protocols.network.Crash`, :class:`protocols.network.Partition`).
    loss, latency, jitter, duplicate, corrupt, bandwidth :
        Shortcuts for the radio's :class:`protocols.network.LinkConfig`.
    **params
        Any field of :class:`sims.simulation.swarm.config.SwarmConfig` (``n_robots``, ``arena``, ...).
        Unknown parameters raise :class:`InputError`.
    """

    metadata = {"render_modes": ["rgb_array"], "name": ENV_NAME, "is_parallelizable": True, "render_fps": 5}

    def __init__(self, scenario: str = "swarm", max_cycles: int = 200, render_mode: str | None = None,
                 crashes: tuple = (), partitions: tuple = (), **params: Any):
        if scenario not in SCENARIOS:
            raise InputError(f"unknown scenario {scenario!r}; known: {', '.join(SCENARIOS)}", field="scenario")
        if render_mode not in (None, "rgb_array"):
            raise InputError(f"render_mode must be None or 'rgb_array', got {render_mode!r}", field="render_mode")
        if not (isinstance(max_cycles, int) and max_cycles >= 1):
            raise InputError("must be a positive integer", field="max_cycles")
        self.max_detections = int(params.pop("max_detections", 32)) if scenario == "assemblies" else 0
        ConfigClass = SwarmConfig if scenario == "swarm" else _assembly_config_class()
        own = {f.name for f in fields(ConfigClass)}
        unknown = sorted(set(params) - own - set(_LINK_KEYS))
        if unknown:
            extra = {"scenario", "max_cycles", "render_mode", "crashes", "partitions"}
            if scenario == "assemblies":
                extra.add("max_detections")
            raise InputError(
                f"unknown parameter(s) {', '.join(unknown)} for scenario {scenario!r}; known: "
                f"{', '.join(sorted(own | set(_LINK_KEYS) | extra))}",
                field="params",
            )
        link_kw = {_LINK_KEYS[k]: params.pop(k) for k in list(params) if k in _LINK_KEYS}
        try:
            config = ConfigClass(**params)
            if link_kw:
                config = replace(config, link=replace(config.link, **link_kw))
        except (TypeError, ValueError) as err:
            if isinstance(err, InputError):
                raise
            raise InputError(str(err), field="params") from None
        self.scenario = scenario
        self.config = config
        self.max_cycles = max_cycles
        self.render_mode = render_mode
        self.crashes, self.partitions = tuple(crashes), tuple(partitions)
        if scenario == "swarm":
            self.possible_agents = list(config.names)
        else:
            from sims.simulation.envs.assembly_sim import AssemblySim

            self.possible_agents = list(AssemblySim(config, 0).names)
        self.agents: list[str] = []
        self._peers = {a: [b for b in self.possible_agents if b != a] for a in self.possible_agents}
        self._seeder = np.random.default_rng()
        self._sim: SwarmSim | None = None
        self._last: StepReport | None = None
        self._cycle = 0
        self._link_history: list[dict] = []

    # ------------------------------------------------------------------ spaces
    @functools.lru_cache(maxsize=None)
    def observation_space(self, agent: str) -> spaces.Dict:
        m = len(self.possible_agents) - 1
        inf = np.float32(np.inf)
        box = lambda shape, lo=-inf, hi=inf: spaces.Box(lo, hi, shape=shape, dtype=np.float32)  # noqa: E731
        if self.scenario == "assemblies":
            return spaces.Dict({
                "detections": box((self.max_detections, 5)),
                "odometry": box((4,)),
                "inbox": box((m, 3), 0.0, _AGE_CAP),
                "estimates": box((m, 5)),
                "converged": box((1,), 0.0, 1.0),
                "own_pose": box((3,)),
            })
        return spaces.Dict({
            "detections": box((m, 4)),
            "odometry": box((4,)),
            "inbox": box((m, 4), 0.0, _AGE_CAP),
            "estimates": box((m, 8)),
            "own_pose": box((6,)),
        })

    @functools.lru_cache(maxsize=None)
    def action_space(self, agent: str) -> spaces.Box:
        c = self.config
        hi = np.array([c.max_speed, c.max_yaw_rate], dtype=np.float32)
        return spaces.Box(-hi, hi, dtype=np.float32)

    # ------------------------------------------------------------------ episode
    def reset(self, seed: int | None = None, options: dict | None = None):
        if seed is not None:
            self._seeder = np.random.default_rng(seed)
        run_seed = int(self._seeder.integers(0, 2**31 - 1))
        if self.scenario == "swarm":
            self._sim = SwarmSim(self.config, run_seed, crashes=self.crashes, partitions=self.partitions)
        else:
            from sims.simulation.envs.assembly_sim import AssemblySim

            self._sim = AssemblySim(self.config, run_seed, crashes=self.crashes, partitions=self.partitions)
        self.agents = list(self.possible_agents)
        self._cycle = 0
        self._link_history = [self._link_counts()]
        self._last = self._sim.step()  # step 0: sense without moving
        self._link_history.append(self._link_counts())
        obs = {a: self._observe(a) for a in self.agents}
        infos = {a: self._info(a) for a in self.agents}
        return obs, infos

    def step(self, actions: dict[str, np.ndarray]):
        if self._sim is None:
            raise InputError("call reset() before step()", field="env")
        c = self.config
        cmd = np.zeros((len(self.possible_agents), 2))
        for i, a in enumerate(self.possible_agents):
            if a in self.agents and a in actions and actions[a] is not None:
                cmd[i] = np.clip(np.asarray(actions[a], dtype=float).reshape(2),
                                 [-c.max_speed, -c.max_yaw_rate], [c.max_speed, c.max_yaw_rate])
        self._last = self._sim.step(cmd)
        self._cycle += 1
        self._link_history.append(self._link_counts())
        self._link_history = self._link_history[-11:]
        live = list(self.agents)
        obs = {a: self._observe(a) for a in live}
        infos = {a: self._info(a) for a in live}
        rewards = {a: self._reward(a) for a in live}
        terminations = {a: False for a in live}
        done = self._cycle >= self.max_cycles
        truncations = {a: done for a in live}
        if done:
            self.agents = []
        return obs, rewards, terminations, truncations, infos

    def close(self) -> None:
        self._sim = None

    # ------------------------------------------------------------------ what an agent has
    def _observe(self, agent: str) -> dict[str, np.ndarray]:
        if self.scenario == "assemblies":
            return self._observe_assembly(agent)
        sim, rep = self._sim, self._last
        robot = sim.robots[agent]
        peers = self._peers[agent]
        index = {p: r for r, p in enumerate(peers)}
        names = self.config.names
        det = np.zeros((len(peers), 4), np.float32)
        for d in rep.sensing.detections[f"{agent}/cam0"]:
            if 0 <= d.node < len(names) and names[d.node] in index:
                det[index[names[d.node]]] = (1.0, d.u, d.v, d.r)
        odo = np.zeros(4, np.float32)
        o = rep.sensing.odometry.get(agent)
        if o is not None:
            odo[:] = (1.0, o.dp[0], o.dp[1], o.dtheta)
        inbox = np.zeros((len(peers), 4), np.float32)
        reports = robot.last_reports
        for p, r in index.items():
            inbox[r, 0] = p in reports["odometry"].fresh
            inbox[r, 1] = p in reports["tracks"].fresh
            est = reports["estimates"]
            inbox[r, 2] = p in est.fresh
            inbox[r, 3] = min(est.ages.get(p, _AGE_CAP), _AGE_CAP)
        ests = np.zeros((len(peers), 8), np.float32)
        current = robot.estimates()
        for p, r in index.items():
            tr = current.get(p)
            if tr is not None:
                sd = np.sqrt(np.diag(tr.cov))
                ests[r] = (1.0, float(tr.yaw_known), *tr.mean, *sd)
        own = np.zeros(6, np.float32)
        own[:3] = robot.pose
        own[3:] = np.sqrt(np.maximum(np.diag(robot.pose_cov), 0.0))
        return {"detections": det, "odometry": odo, "inbox": inbox, "estimates": ests, "own_pose": own}

    def _observe_assembly(self, agent: str) -> dict[str, np.ndarray]:
        sim, rep = self._sim, self._last
        peers = self._peers[agent]
        det = np.zeros((self.max_detections, 5), np.float32)
        rows = sorted((key, d.node, d.u, d.v, d.r) for key, dets in rep.step.detections.items()
                      if key.startswith(agent + "/") for d in dets)
        for r, (_, node, u, v, rad) in enumerate(rows[: self.max_detections]):
            det[r] = (1.0, node, u, v, rad)
        odo = np.zeros(4, np.float32)
        o = rep.step.odometry.get(agent)
        if o is not None:
            odo[:] = (1.0, o.dp[0], o.dp[1], o.dtheta)
        agent_obj = sim.agents[agent]
        ages = agent_obj.ages if not callable(agent_obj.ages) else agent_obj.ages()
        neigh = set(agent_obj.neighbours)
        inbox = np.zeros((len(peers), 3), np.float32)
        est = np.zeros((len(peers), 5), np.float32)
        for r, p in enumerate(peers):
            inbox[r] = (p in sim.last_heard[agent], min(ages.get(p, _AGE_CAP), _AGE_CAP), p in neigh)
            pose = rep.estimates[agent].get(p)
            if pose is not None:
                est[r] = (1.0, *np.asarray(pose.p, float), pose.theta)
        return {"detections": det, "odometry": odo, "inbox": inbox, "estimates": est,
                "converged": np.array([float(rep.converged[agent])], np.float32),
                "own_pose": sim.own_pose[agent].astype(np.float32)}

    def _info(self, agent: str) -> dict:
        """Errors against truth (evaluation only) and the agent's traffic, for either scenario."""
        errs = sorted(self._last.errors[agent].items())
        if self.scenario == "assemblies":
            pos = {t: e[0] for t, e in errs}
            yaw = {t: e[1] for t, e in errs}
            extra = {"converged": self._last.converged[agent]}
        else:
            pos = {t: e.position for t, e in errs}
            yaw = {t: e.yaw for t, e in errs if e.yaw is not None}
            extra = {"own_pose_error": self._last.own_pose_error[agent]}
        sent = self._sim.network.stats().per_sender.get(agent)
        return {
            "position_error": pos,
            "yaw_error": yaw,
            "mean_position_error": float(np.mean(list(pos.values()))) if pos else None,
            "mean_yaw_error": float(np.mean(list(yaw.values()))) if yaw else None,
            "tracked": len(pos),
            **extra,
            "messages_sent": 0 if sent is None else sent.sent,
            "bytes_sent": 0 if sent is None else sent.bytes_sent,
            "step": self._last.k,
        }

    def _reward(self, agent: str) -> float:
        errs = self._last.errors[agent]
        m = len(self._peers[agent])
        if not errs:
            return 0.0
        pos = [e[0] if isinstance(e, tuple) else e.position for e in errs.values()]
        return float(len(errs) / m - np.mean(pos))

    # ------------------------------------------------------------------ rendering
    def _link_counts(self) -> dict:
        if self._sim is None:
            return {}
        return {k: (v.sent, v.delivered, v.dropped) for k, v in self._sim.network.stats().per_link.items()}

    def link_loss(self) -> dict[tuple[int, int], float]:
        """Recent (last 10 steps) loss fraction per undirected robot pair with traffic."""
        if len(self._link_history) < 2:
            return {}
        old, new = self._link_history[0], self._link_history[-1]
        idx = {n: i for i, n in enumerate(self.possible_agents)}
        acc: dict[tuple[int, int], list[int]] = {}
        for (a, b), (s, d, x) in new.items():
            s0, d0, x0 = old.get((a, b), (0, 0, 0))
            key = tuple(sorted((idx[a], idx[b])))
            tot = acc.setdefault(key, [0, 0])
            tot[0] += x - x0
            tot[1] += (d - d0) + (x - x0)
        return {k: v[0] / v[1] for k, v in acc.items() if v[1] > 0}

    def render(self) -> np.ndarray | None:
        if self.render_mode is None or self._sim is None:
            return None
        from sims.simulation.envs.drawing import camera_view, compose_frame, top_view

        if self.scenario == "assemblies":
            return self._render_assemblies()
        c, rep = self.config, self._last
        estimates = {}
        for i, a in enumerate(self.possible_agents):
            items = []
            R = rot2(rep.state[i, 2])
            for name, tr in self._sim.robots[a].estimates().items():
                items.append((c.names.index(name), compose(rep.state[i], tr.mean), R @ tr.cov[:2, :2] @ R.T))
            estimates[i] = items
        top = top_view(rep.state, c.arena, estimates=estimates, link_loss=self.link_loss(),
                       max_angle=np.radians(c.max_angle_deg), max_distance=c.max_distance,
                       node_radius=c.node_radius)
        cams = [
            camera_view([(d.node, d.u, d.v, d.r) for d in rep.sensing.detections[f"{a}/cam0"]],
                        c.image_width, c.image_height, label=a)
            for a in self.possible_agents
        ]
        frame = compose_frame(top, cams)
        return np.ascontiguousarray(frame)  # colours were given in RGB order


    def _render_assemblies(self) -> np.ndarray:
        from sims.simulation.envs.drawing import camera_view, compose_frame, top_view

        sim, rep = self._sim, self._last
        world = sim.world([rep.state], rep.t)
        nodes = []
        for i, a in enumerate(world.assemblies):
            centres = a.root_pose(0, sim.node_radius).apply(a.shapes[0].centres)
            nodes.append((i, centres[:, :2]))
        lo = min(float(c[:, :2].min()) for _, c in nodes) - 1.0
        hi = max(float(c[:, :2].max()) for _, c in nodes) + 1.0
        shift = np.array([lo, lo, 0.0])
        fans = []
        for rig in sim.cameras:
            i = self.possible_agents.index(rig.assembly)
            cam = world.camera_in_world(rig, 0)
            fans.append((i, cam.p[:2] - shift[:2], float(np.arctan2(cam.R[1, 2], cam.R[0, 2]))))  # optical axis
        estimates = {}
        for i, a in enumerate(self.possible_agents):
            estimates[i] = [(self.possible_agents.index(m), compose(rep.state[i], np.array([pose.p[0], pose.p[1], pose.theta])) - shift)
                            for m, pose in sorted(rep.estimates[a].items())]
        top = top_view(rep.state - shift, hi - lo, estimates=estimates, link_loss=self.link_loss(),
                       max_angle=0.6, max_distance=2.0, node_radius=sim.node_radius,
                       nodes=[(i, xy - shift[:2]) for i, xy in nodes], fans=fans)
        cams = [camera_view([(d.node, d.u, d.v, d.r) for d in rep.step.detections.get(rig.key, ())],
                            rig.spec.width, rig.spec.height, label=rig.key) for rig in sim.cameras]
        return np.ascontiguousarray(compose_frame(top, cams))


def _assembly_config_class():
    from sims.simulation.envs.assembly_sim import AssemblySimConfig

    return AssemblySimConfig


def raw_env(**config: Any) -> RelativeLocalizationEnv:
    """The env itself (no wrappers)."""
    return RelativeLocalizationEnv(**config)


def parallel_env(**config: Any) -> RelativeLocalizationEnv:
    """PettingZoo entry point: ``sims.simulation.envs.relative_localization_v0.parallel_env(**config)``."""
    return raw_env(**config)
