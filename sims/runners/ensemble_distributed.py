"""Run Funiak et al.'s distributed localization (§V) as one agent per module over the simulated network.

:func:`run_distributed` builds a :class:`agents.modules.ModuleAgent` per module from its own
observations, attaches all of them to a :class:`protocols.network.SimulatedNetwork` (lossless by
default; ``loss`` = probability that a message copy is dropped; then every message is acknowledged
and retransmitted until it is, so a lossy run computes what a lossless one does, with more
messages), and drives the phases of the distributed Algorithm 1 level
by level: top-down (leader election and tree, graph abstraction, normalized cut, leaves), then
bottom-up (rigid alignment, refinement). The runner is only a round clock: in each round every agent
that has something to do hands over its outbox, the network moves the messages, and each agent's
handlers see its own deliveries. A phase ends when no message is in flight and no agent waits for an
acknowledgement (the simulator's termination detection). Every message is counted by phase and by
sending module; the counts are checked against the network's own counters.

The refinement (about 90 % of the messages) runs by default through
:class:`agents.modules.BatchedRefinement`: the same handlers in lockstep over arrays, the same
messages handed to the network in one batched call per round and kind (exact counts, sizes, losses
and rounds; tested against the per-message path, lossless and lossy). ``batched=False`` keeps every
message on the per-message path.
"""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from agents.modules.agent import ModuleAgent, ModuleConfig
from agents.modules.batched import BatchedRefinement
from decentral.ensemble import EnsembleEstimate, EnsembleProblem, HierarchyConfig
from decentral.ensemble.hierarchical import layout_components
from decentral.ensemble.model import residuals_from_matrices
from decentral.errors import ProtocolError
from protocols.ensemble.messages import PHASES
from protocols.network import LinkConfig, NetworkConfig, SimulatedNetwork

__all__ = ["DistributedConfig", "DistributedResult", "run_distributed"]


@dataclass(frozen=True)
class DistributedConfig:
    """Parameters of a distributed run.

    Attributes
    ----------
    hierarchy : HierarchyConfig
        Shared with the centralized method (leaf size, abstraction size, tolerances).
    loss : float
        Probability that a message copy is dropped by the network.
    check_every : int
        Refinement iterations between convergence checks.
    level_max_iter, top_max_iter : int
        Caps on refinement iterations below the top and at the top.
    step : float
        Damping of each module's position update.
    momentum : float
        Heavy-ball momentum of each module's position update.
    top_gtol : float
        Largest gradient entry (module radii) at which the top-level refinement stops. Local
        iterations converge linearly, so the default is looser than the centralized final 1e-6.
    max_rounds : int
        Safety cap on the rounds of one phase (a protocol that does not settle raises).
    batched : bool
        Run the refinement through :class:`agents.modules.BatchedRefinement` (same messages,
        counts, losses, rounds and answer as the per-message path; on a lossless network about
        two orders of magnitude faster for that phase).
    """

    hierarchy: HierarchyConfig = HierarchyConfig()
    loss: float = 0.0
    check_every: int = 10
    level_max_iter: int = 400
    top_max_iter: int = 3000
    step: float = 1.0
    momentum: float = 0.9
    top_gtol: float = 1e-4
    max_rounds: int = 100_000
    batched: bool = True


@dataclass(frozen=True)
class DistributedResult:
    """Outcome of a distributed run.

    Attributes
    ----------
    estimate : EnsembleEstimate
        Every module's own final pose (components laid side by side, as the centralized method does).
    cost : float
        Negative log-likelihood at the estimate.
    messages : ndarray of int, shape (n,)
        Messages sent by each module (retransmissions and acknowledgements included).
    phase_names : tuple of str
    phase_messages : ndarray of int, shape (len(phase_names),)
        Messages per phase.
    rounds : int
        Network rounds used.
    levels : int
        Depth of the hierarchy.
    network : dict
        The network's counters (:meth:`protocols.transport.TransportStats.as_dict` totals and drops).
    info : dict
        Timings, leader notes, ``refine_iterations`` per level, and ``capped_levels``: the levels
        whose refinement stopped at its iteration cap (``top_max_iter`` at level 0, else
        ``level_max_iter``) instead of at the gradient tolerance.
    """

    estimate: EnsembleEstimate
    cost: float
    messages: np.ndarray
    phase_names: tuple[str, ...]
    phase_messages: np.ndarray
    rounds: int
    levels: int
    network: dict
    info: dict = field(default_factory=dict)


class _Driver:
    def __init__(self, agents: list[ModuleAgent], net: SimulatedNetwork, max_rounds: int):
        self.agents, self.net, self.max_rounds = agents, net, max_rounds
        self.round = 0

    def phase(self, start, members=None) -> None:
        """Call ``start(agent)`` on ``members`` (default all) and run rounds until the phase settles."""
        agents = self.agents
        active = set(range(len(agents))) if members is None else set(members)
        for a in active:
            start(agents[a])
        for _ in range(self.max_rounds):
            self.round += 1
            t = float(self.round)
            receivers: set[int] = set()
            for a in sorted(active):
                for msg in agents[a].flush(self.round):
                    self.net.send(msg, t)
                    receivers.add(int(msg.receiver))
            nxt = {a for a in active if agents[a].busy}
            for r in sorted(receivers):
                for d in self.net.poll(str(r), t):
                    agents[r].handle(d.message)
                    nxt.add(r)
            active = nxt
            if not active:
                return
        raise ProtocolError(f"a phase did not settle within {self.max_rounds} rounds")


def run_distributed(problem: EnsembleProblem, rng: np.random.Generator,
                    config: DistributedConfig = DistributedConfig(),
                    progress: Callable[..., None] | None = None) -> DistributedResult:
    """Localize every module by the distributed Algorithm 1 (Funiak et al. 2008 §V).

    Parameters
    ----------
    problem : EnsembleProblem
        The observations; module k receives only rows with ``i == k``.
    rng : numpy.random.Generator
        Split into the network's stream and one stream per module (cluster-leader election).
    config : DistributedConfig
    progress : callable, optional
        Called after each stage (the set-up phases, each level's top-down build, each level's
        refinement) as ``progress(stages_done, stages_total, stage=..., messages=...)``;
        ``stages_total`` is ``None`` until the depth of the hierarchy is known.
    """
    t0 = time.perf_counter()
    n, d = problem.n, problem.dim
    net_rng, module_seed = rng.spawn(2)
    module_rngs = [np.random.default_rng(s) for s in np.random.SeedSequence(
        int(module_seed.integers(0, 2**63))).spawn(n)]
    order = np.argsort(problem.i, kind="stable")
    bounds = np.searchsorted(problem.i[order], np.arange(n + 1))
    agents = []
    for k in range(n):
        rows = order[bounds[k]:bounds[k + 1]]
        cfg = ModuleConfig(k, d, problem.radius, problem.j[rows].copy(), problem.z[rows].copy(), config.hierarchy,
                           config.check_every, config.level_max_iter, config.top_max_iter, config.step,
                           config.momentum, config.top_gtol, reliable=config.loss > 0)
        agents.append(ModuleAgent(cfg, module_rngs[k]))
    net = SimulatedNetwork(NetworkConfig(tuple(a.name for a in agents), link=LinkConfig(drop=config.loss)), net_rng)
    drv = _Driver(agents, net, config.max_rounds)
    stages = [0, None]  # done, total

    def tell(stage: str) -> None:
        stages[0] += 1
        if progress is not None:
            progress(stages[0], stages[1], stage=stage, messages=net.stats().total.sent)

    def refining(level: int):
        """Per-check callback of a level's refinement: same stage count, the iterations so far."""
        if progress is None:
            return None
        return lambda it, live: progress(stages[0], stages[1], stage=f"level {level} refinement",
                                         iteration=it, refining=live)

    drv.phase(lambda a: a.begin_hello())
    drv.phase(lambda a: a.begin_election())
    drv.phase(lambda a: a.begin_join(0))
    drv.phase(lambda a: a.begin_count())
    tell("set-up")
    level = 0
    while True:
        if level > 0:
            members = [k for k, a in enumerate(agents) if level in a.levels]
            drv.phase(lambda a: a.begin_tree(level), members)
            drv.phase(lambda a: a.begin_join(level), members)
        members = [k for k, a in enumerate(agents) if level in a.levels]
        drv.phase(lambda a: a.begin_leaf(level), members)
        drv.phase(lambda a: a.begin_cluster(level), members)
        drv.phase(lambda a: a.begin_abstract(level), members)
        tell(f"level {level} cut")
        if not any(level + 1 in a.levels for a in agents):
            break
        level += 1
    depth = level
    stages[1] = stages[0] + depth
    iterations = {}
    t_refine = 0.0
    for lv in range(depth - 1, -1, -1):
        members = [k for k, a in enumerate(agents) if lv + 1 in a.levels and not a.levels[lv].leaf]
        if not members:
            tell(f"level {lv} refinement")
            continue
        drv.phase(lambda a: a.begin_boundary(lv), members)
        drv.phase(lambda a: a.begin_align(lv), members)
        if config.batched:
            t1 = time.perf_counter()
            iterations[lv], drv.round = BatchedRefinement(agents, members, lv, net, config.check_every,
                                                          drv).run(drv.round, refining(lv))
            t_refine += time.perf_counter() - t1
            tell(f"level {lv} refinement")
            continue
        for k in members:
            agents[k].begin_refine(lv)
        it = 0
        while True:
            live = [k for k in members if agents[k].refining(lv)]
            if not live:
                break
            drv.phase(lambda a: a.refine_send(lv), live)
            for k in live:
                agents[k].refine_update(lv)
            it += 1
            if it % config.check_every == 0:
                drv.phase(lambda a: a.begin_grad(lv), live)
                if progress is not None:
                    refining(lv)(it, len(live))
        iterations[lv] = it
        tell(f"level {lv} refinement")

    position = np.array([a.position for a in agents])
    rotation = np.array([a.rotation for a in agents])
    # components were localized independently, each in its own frame: lay them side by side
    group0 = np.array([a.levels[0].group for a in agents])
    comps = [np.flatnonzero(group0 == g) for g in np.unique(group0)]
    comps.sort(key=lambda m: (-m.size, m[0]))
    component = np.zeros(n, dtype=np.int64)
    if len(comps) > 1:
        for c, (m, p) in enumerate(zip(comps, layout_components([position[m] for m in comps], problem.radius))):
            position[m] = p
            component[m] = c
    est = EnsembleEstimate(position, rotation, component)
    r = residuals_from_matrices(problem, position, rotation)
    cost = 0.5 * float(np.einsum("ea,ea->", r, r))

    per_phase = Counter()
    for a in agents:
        per_phase.update(a.sent)
    messages = np.array([sum(a.sent.values()) for a in agents], dtype=np.int64)
    stats = net.stats()
    if stats.total.sent != int(messages.sum()):
        raise ProtocolError(f"message count mismatch: agents {int(messages.sum())}, network {stats.total.sent}")
    return DistributedResult(
        estimate=est,
        cost=cost,
        messages=messages,
        phase_names=PHASES,
        phase_messages=np.array([per_phase.get(p, 0) for p in PHASES], dtype=np.int64),
        rounds=drv.round,
        levels=depth,
        network={"total": stats.total.as_dict(), "drop_reasons": dict(stats.drop_reasons)},
        info={"seconds": time.perf_counter() - t0, "seconds_batched_refinement": t_refine,
              "refine_iterations": iterations,
              "capped_levels": [lv for lv, it in sorted(iterations.items())
                                if it >= (config.top_max_iter if lv == 0 else config.level_max_iter)],
              "refine_share_rounds": int(sum(a.share_rounds for a in agents)),
              "refine_pose_shares": int(sum(a.shares_sent for a in agents)),
              "batched": bool(config.batched),
              "notes": [e for a in agents for e in a.events]},
    )
