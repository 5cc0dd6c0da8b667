"""Drive one :class:`agents.assembly.AssemblyAgent` per assembly over a simulated lossy network for a log.

The runner is the simulator, not a participant: it hands each agent its own sensors' data step by
step (:func:`own_step`, never another assembly's data nor ground truth), moves messages through a
seeded :class:`protocols.SimulatedNetwork`, and runs ADMM rounds (two phases each, half a round
period apart) through the same :class:`agents.runtime.AgentHost` a process uses. Each agent decides
alone when its window is done (:class:`agents.runtime.WindowRule`: its own convergence flag held for
``settle`` rounds, or the round budget ``max_rounds``) and freezes its estimate of the step then; the
next log step comes once every live agent has gone quiet and nothing is in flight (nothing would
happen before the next sensor step) or after ``max_rounds``. The estimate it returns is the reference
agent's own frozen estimates, in ``decentral.estimate/1`` form, with message, byte and round counts
per kind and per agent in ``stats``.

A crashed agent (:class:`protocols.Crash`) is skipped while down and restarts with empty state when
it comes back (it must catch up from its peers); a partition only cuts links.
"""

from __future__ import annotations

import time
from typing import Callable
from dataclasses import dataclass, field

import numpy as np

from agents.assembly import AgentConfig, AssemblyAgent, OwnStep
from agents.runtime import AgentHost, LocalAgent, WindowRule
from decentral.admm import AdmmConfig
from decentral.errors import InputError
from decentral.factors import NoiseModel
from decentral.observations import Estimate, EstimateStep, ObservationLog, require_log, resolve_reference
from decentral.unplaced import count_reasons
from protocols.network import Crash, LinkConfig, NetworkConfig, Partition, SimulatedNetwork
from sims.runners.run_status import placed_steps, run_status

__all__ = ["AdmmRunConfig", "AdmmRun", "own_step", "run_admm"]


@dataclass(frozen=True)
class AdmmRunConfig:
    """Parameters of a decentralized run.

    Attributes
    ----------
    window : int
        Sliding-window length K.
    noise : NoiseModel
        Factor weights (as for the centralized estimator).
    admm : AdmmConfig
        ADMM parameters.
    loss, duplicate : float
        Per-copy drop and duplication probabilities of every link.
    mtu : int
        0 (default): ``loss`` is per copy. Otherwise ``loss`` is per datagram of this size, as the UDP
        transport cuts frames (parity included; :attr:`protocols.link_config.LinkConfig.mtu`), so that a
        simulation predicts processes on a radio that loses packets.
    latency, jitter : float
        Link delay and its uniform jitter (s); jitter beyond half a round period reorders and delays.
    round_period : float
        Simulated seconds per ADMM round.
    max_rounds, min_rounds, settle : int
        Each agent's local window rule (:class:`agents.runtime.WindowRule`): its window is done once its
        own convergence flag held ``settle`` rounds in a row (after ``min_rounds``), or after the round
        budget ``max_rounds`` between sensor steps.
    crashes, partitions : tuple
        Fault schedule in simulated network time (``round * round_period``).
    announce_every : int
        Configuration re-announcement period (steps).
    share_forms : {"first", "every", "never"}
        When the agents share their cost forms and start the ADMM at the joint solution
        (:class:`agents.assembly.AgentConfig`): the cold start only, every step (default), or never.
    aggregation : {"tree", "broadcast"}
        How the forms travel once agents know their route to the reference: up and down a spanning
        tree of the view graph (default) or broadcast by every agent (the cold start's way).
    background : bool
        A window not done when the next step comes goes on beside it until the step after and revises its
        step's provisional answer if it converges (:attr:`agents.runtime.WindowRule.background`).
    fast_forward : bool
        Start the next step as soon as every live agent is quiet and nothing is in flight (default:
        nothing would happen before it); ``False`` runs every step's whole round budget, as processes at
        a fixed pace do (the estimates and message counts are the same).
    """

    window: int = 5
    noise: NoiseModel = field(default_factory=NoiseModel)
    admm: AdmmConfig = field(default_factory=AdmmConfig)
    loss: float = 0.0
    duplicate: float = 0.0
    mtu: int = 0
    latency: float = 0.0005
    jitter: float = 0.001
    round_period: float = 0.01
    max_rounds: int = 300
    min_rounds: int = 2
    settle: int = 2
    crashes: tuple[Crash, ...] = ()
    partitions: tuple[Partition, ...] = ()
    announce_every: int = 5
    share_forms: str = "every"
    aggregation: str = "tree"
    background: bool = True
    fast_forward: bool = True

    def __post_init__(self) -> None:
        if not (isinstance(self.window, int) and self.window >= 1):
            raise InputError(f"must be an integer >= 1, got {self.window!r}", field="window")
        if not 0.0 <= self.loss < 1.0:
            raise InputError(f"must be in [0, 1), got {self.loss!r}", field="loss")
        if not (self.max_rounds >= 1 and self.settle >= 1 and self.min_rounds >= 0):
            raise InputError("need max_rounds >= 1, settle >= 1, min_rounds >= 0", field="max_rounds")


@dataclass(frozen=True)
class AdmmRun:
    """Result of :func:`run_admm`.

    Attributes
    ----------
    estimate : Estimate
        The reference agent's estimates per step (``decentral.estimate/1`` in memory).
    rounds : tuple of int
        ADMM rounds run at each step.
    converged : tuple of bool
        Whether every live agent had converged at the end of each step.
    agent_estimates : tuple of dict
        Per step, agent -> its own estimates (name -> PlanarPose, in that agent's frame).
    stats : dict
        JSON-ready counts (also inside ``estimate.stats``).
    messages_per_step : tuple of dict
        Per log step, message kind -> messages sent by each agent (list in the order of
        ``log.assemblies``; a broadcast counts once per receiver, as in the network's counts). Kept out
        of ``stats`` so that the estimate file stays small on long logs.
    bytes_per_step : tuple of dict
        The same in bytes (wire frames as the simulated network sizes them, without a real
        transport's envelope).
    """

    estimate: Estimate
    rounds: tuple[int, ...]
    converged: tuple[bool, ...]
    agent_estimates: tuple[dict, ...]
    stats: dict
    messages_per_step: tuple[dict, ...] = ()
    bytes_per_step: tuple[dict, ...] = ()


def _note_without(without: dict, step: int, names) -> None:
    """Record (or clear, when ``names`` is empty) the agents a converged step's forms lacked."""
    if names:
        without[step] = sorted(names)
    else:
        without.pop(step, None)


def own_step(log: ObservationLog, name: str, k: int) -> OwnStep:
    """What assembly ``name``'s own sensors give at step ``k`` of ``log`` (nothing of the others)."""
    step = log.steps[k]
    prefix = name + "/"
    return OwnStep(
        step=k,
        t=step.t,
        config=dict(step.config.get(name, {})),
        odometry=step.odometry.get(name),
        detections={key: d for key, d in step.detections.items() if key.startswith(prefix)},
        mounts={key: m for key, m in step.mounts.items() if key.startswith(prefix)},
    )


def _agent_config(log: ObservationLog, name: str, reference: str, config: AdmmRunConfig) -> AgentConfig:
    cams = tuple(cam for cam in log.cameras.values() if cam.assembly == name)
    return AgentConfig(name=name, assemblies=tuple(log.assemblies), reference=reference, cameras=cams,
                       node_radius=log.node_radius, noise=config.noise, window=config.window, admm=config.admm,
                       announce_every=config.announce_every, share_forms=config.share_forms,
                       aggregation=config.aggregation,
                       share_timeout=_rule(config).share_timeout(AgentConfig.share_timeout))


def _rule(config: AdmmRunConfig) -> WindowRule:
    """Each agent's local window rule (the same one a process runs, with the budget ``max_rounds``)."""
    return WindowRule(min_rounds=config.min_rounds, settle=config.settle, budget=config.max_rounds,
                      background=config.background)


def run_admm(log: ObservationLog, reference: str | None = None, config: AdmmRunConfig = AdmmRunConfig(),
             seed: int = 0, progress: Callable[..., None] | None = None) -> AdmmRun:
    """Run the decentralized estimator over ``log`` and return the reference agent's estimate.

    Parameters
    ----------
    log : ObservationLog
        Observations of every assembly (each agent gets only its own, step by step).
    reference : str, optional
        The assembly whose agent pins the gauge and whose estimates are returned (default: first).
    config : AdmmRunConfig
        Network, ADMM and schedule parameters.
    seed : int
        Seed of the network's randomness (losses, duplicates, jitter); the run is deterministic in it.
    progress : callable, optional
        Called after each log step as ``progress(steps_done, steps_total, rounds=..., messages=...,
        unconverged=...)`` (running totals: rounds, copies sent, steps that hit ``max_rounds``).

    Examples
    --------
    One agent per assembly over a lossless simulated network; the reference agent's estimate matches
    the centralized one:

    >>> from decentral.synthetic import camera, circle_motion, l_config, make_log
    >>> world = {"A": circle_motion(3, (0, 0), 1.0, 0.0, 0.1, 0.0), "B": circle_motion(3, (0, 0), 1.0, 0.8, 0.1, 0.0)}
    >>> log = make_log(world, {"A": l_config([0, 1, 2, 3]), "B": l_config([10, 11, 12, 13])}, [camera("A", yaw=0.5)])
    >>> run = run_admm(log, config=AdmmRunConfig(window=3), seed=0)
    >>> [sorted(step.poses) for step in run.estimate.steps], run.stats["all_converged"]
    ([['B'], ['B'], ['B']], True)
    >>> from decentral.estimator import estimate_log
    >>> from decentral.metrics import estimate_gap
    >>> gap_m, gap_deg, mismatched = estimate_gap(estimate_log(log), run.estimate)
    >>> bool(gap_m < 1e-3 and gap_deg < 0.1), mismatched
    (True, 0)
    """
    log = require_log(log)
    if not isinstance(config, AdmmRunConfig):
        raise InputError(f"expected an AdmmRunConfig, got {type(config).__name__}", field="config")
    reference = resolve_reference(log, reference)
    start = time.perf_counter()
    names = tuple(log.assemblies)
    net = SimulatedNetwork(NetworkConfig(
        agents=names,
        link=LinkConfig(drop=config.loss, latency=config.latency, jitter=config.jitter, duplicate=config.duplicate,
                        mtu=config.mtu),
        partitions=config.partitions, crashes=config.crashes, round_period=config.round_period,
    ), np.random.default_rng(seed))
    rule = _rule(config)
    position = {n: i for i, n in enumerate(names)}
    per_step: list[dict] = []  # per step: kind -> copies sent by each agent (names order)
    bytes_step: list[dict] = []  # the same in bytes

    sent_total = 0

    def count(message):
        nonlocal sent_total
        copies = len(names) - 1 if message.is_broadcast else 1
        sent_total += copies
        row = per_step[-1].setdefault(message.KIND, [0] * len(names))
        row[position[message.sender]] += copies
        row = bytes_step[-1].setdefault(message.KIND, [0] * len(names))
        row[position[message.sender]] += copies * message.size_bytes

    def host(n: str) -> AgentHost:
        return AgentHost(LocalAgent(AssemblyAgent(_agent_config(log, n, reference, config)), rule), net, count)

    hosts = {n: host(n) for n in names}
    was_down = {n: False for n in names}
    half = 0
    rounds_global = 0
    now = lambda: half * config.round_period / 2  # noqa: E731
    rounds, converged, per_agent, est_steps = [], [], [], []
    restarts = {n: 0 for n in names}
    tick_seconds = 0.0
    excluded: set[str] = set()
    suspects: set[str] = set()
    agent_converged: list[dict[str, bool]] = []  # per step: live agent -> its window converged (or was revised)
    revised: list[dict] = []  # the reference's revised steps (stats["revised"])
    without: dict[int, list] = {}  # the reference's converged steps whose forms lacked some agents' (given up on)

    def take_revisions() -> None:
        """Windows that converged in the background (or ended with more forms) replace their steps' provisional
        answers."""
        for n, h in hosts.items():
            for rev in h.agent.take_revisions():
                agent_converged[rev.step][n] = rev.converged
                per_agent[rev.step][n] = rev.poses
                if n == reference:
                    est_steps[rev.step] = EstimateStep(log.steps[rev.step].t, rev.poses, rev.unplaced)
                    revised.append({"step": rev.step, "rounds": rev.rounds, "at_step": len(est_steps),
                                    "reason": rev.reason})
                    _note_without(without, rev.step, rev.without)
    def run_step_period() -> int:
        """Rounds until the next step: it comes when every live agent has ended its window by its own rule and
        nothing is in flight (what processes do while they wait for the next sensor step), or after the round
        budget. Returns the rounds run."""
        nonlocal half, rounds_global, tick_seconds
        r = 0
        while r < config.max_rounds:
            for phase in (0, 1):
                half += 1
                t = now()
                t0 = time.perf_counter()
                for n in names:
                    if not net.is_down(n, t):
                        hosts[n].half_round(t, rounds_global, phase)
                tick_seconds += time.perf_counter() - t0
            r += 1
            rounds_global += 1
            take_revisions()
            live = [n for n in names if not net.is_down(n, now())]
            if (config.fast_forward and all(hosts[n].agent.quiet for n in live)
                    and not any(net.pending(n) for n in live)):
                break
        return r

    for k in range(len(log.steps)):
        t = now()
        per_step.append({})
        bytes_step.append({})
        for n in names:
            down = net.is_down(n, t)
            if was_down[n] and not down:
                hosts[n] = host(n)  # restarts empty
                restarts[n] += 1
            was_down[n] = down
            if not down:
                hosts[n].on_step(own_step(log, n, k), t, rounds_global)
        r = run_step_period()
        live = [n for n in names if not net.is_down(n, now())]
        for n in live:
            hosts[n].agent.end_window()
        rounds.append(r)
        agent_converged.append({n: hosts[n].agent.converged for n in live})
        per_agent.append({n: hosts[n].agent.window_estimate for n in live})
        ref_poses = hosts[reference].agent.window_estimate if reference in live else {}
        if reference in live:  # members whose data the others contradicted (decentral.consistency)
            if hosts[reference].agent.converged:
                _note_without(without, k, getattr(hosts[reference].agent.agent, "without", ()))
            excluded |= set(getattr(hosts[reference].agent.agent, "excluded", ()))
            suspects |= set(getattr(hosts[reference].agent.agent, "suspects", ()))
        why = (hosts[reference].agent.window_unplaced if reference in live
               else {n: "no_consensus" for n in names if n != reference})
        est_steps.append(EstimateStep(log.steps[k].t, ref_poses, why))
        if progress is not None:
            progress(k + 1, len(log.steps), rounds=int(sum(rounds)), messages=sent_total,
                     unconverged=sum(1 for c in agent_converged if not (c and all(c.values()))))
    # the last step's next step would come now: an unfinished last window goes on in the background for one
    # more step period, as every other window does (its rounds and messages count to the last step)
    live = [n for n in names if not net.is_down(n, now())]
    for n in live:
        hosts[n].agent.end_of_log()
    if log.steps and any(hosts[n].agent.waiting_in_background for n in live):
        rounds[-1] += run_step_period()
    for n in names:
        if not net.is_down(n, now()):
            hosts[n].agent.end_background()
    take_revisions()
    converged = [bool(c) and all(c.values()) for c in agent_converged]
    agents = {n: h.agent.agent for n, h in hosts.items()}
    transport = net.stats().as_dict()
    seconds = time.perf_counter() - start
    total_rounds = int(sum(rounds))
    unplaced = count_reasons(step.unplaced for step in est_steps)
    without = {k: v for k, v in without.items() if converged[k]}
    status, status_counts = run_status(converged, placed_steps(est_steps), unplaced,
                                       revised_because=[r["reason"] for r in revised], without=len(without))
    stats = {
        "estimator": "consensus-admm",
        "mode": "admm",
        "window": config.window,
        "loss": config.loss,
        "mtu": config.mtu,
        "duplicate": config.duplicate,
        "seed": seed,
        "rounds_per_step": rounds,
        "rounds_total": total_rounds,
        "converged_per_step": converged,
        "all_converged": bool(all(converged)),
        # steps answered provisionally whose window then converged in the background (agents.runtime): the
        # reference's revisions, with the rounds the window took and the step under way when it converged
        "revised": revised,
        # converged steps whose window lacked some agents' forms (given up on as down): the others' data only
        "converged_without": [{"step": k, "without": v} for k, v in sorted(without.items())],
        "agents": {
            n: {
                "converged": agents[n].converged,
                "ready": agents[n].ready,
                "neighbours": list(agents[n].neighbours),
                "restarts": restarts[n],
                **agents[n].counters,
                **{f"sent_{key}": v for key, v in transport["per_sender"].get(n, {}).items()
                   if key in ("sent", "bytes_sent")},
            }
            for n in names
        },
        "messages": transport,
        "unplaced": unplaced,
        "status": status,
        "status_counts": status_counts,
        "seconds": seconds,
        "seconds_per_round": tick_seconds / max(total_rounds, 1),
        "admm": {"rho0": config.admm.rho0, "mu": config.admm.mu, "tau": config.admm.tau,
                 "alpha": config.admm.alpha, "metric": config.admm.metric, "metric_floor": config.admm.metric_floor,
                 "eps_rot": config.admm.eps_rot, "eps_pos": config.admm.eps_pos, "share_forms": config.share_forms,
                 "aggregation": config.aggregation},
        "stray_detections": sum(step.stray_detections() for step in log.steps),
        # members the reference left out of its joint solutions, their data contradicted by the others'
        "excluded": sorted(excluded),
        # windows whose data were inconsistent with no one member to blame: the members that could explain it
        "suspects": sorted(suspects),
    }
    estimate = Estimate(reference, tuple(est_steps), stats)
    return AdmmRun(estimate, tuple(rounds), tuple(converged), tuple(per_agent), stats,
                   tuple({kind: row for kind, row in sorted(c.items())} for c in per_step),
                   tuple({kind: row for kind, row in sorted(c.items())} for c in bytes_step))
