"""One agent as an operating-system process: its part of the log, a real transport, the wall clock.

This is the process runtime of :mod:`agents.runtime`: the same :class:`agents.runtime.AgentHost`
the simulated runner drives, here for one agent, on wall-clock timers:

- **steps**: step ``k`` of the part is handed to the agent at ``start + (t_k - t_0) / rate`` (the
  log's pace, or ``rate`` times faster); a process that starts late (a restart) begins with the
  step under way and never sees the ones it missed;
- **rounds**: half round ``h`` runs at ``start + h * round_period / 2`` (phase ``h % 2`` of round
  ``h // 2``); every process of a run counts rounds from the same ``start``, so their round numbers
  agree (the aggregation tree names start rounds); a half round missed under load is skipped; a
  process told a later start than a peer finds it from the peer's round numbers and follows the
  earliest start (:mod:`sims.runners.start_clock`; reported in ``stats["clock"]``);
- **the window** ends by the agent's own rule (:class:`agents.runtime.WindowRule`, budget = the
  rounds between two steps) or when the next step comes; its estimate is what the agent holds then;
- **after the last step** the last window ends when its next step would be due, like every other (one
  step period); if it ended unconverged it goes on in the background for one more step period, as every
  other window does; the agent keeps answering for ``linger`` seconds after the last step in any case,
  then stops.

Each finished step is appended at once as one JSON line to ``stream`` (if given): ``{"step", "t",
"poses", "unplaced", "converged", "rounds", "window_seconds", "counts", "heard", "latency_ms",
"behind_ms", "lagged", "cpu_ms", "counters", "closed_at"}`` with the transport's cumulative counts, the frame latencies of the
window (median, p90, max, ms), how late the process ran its half rounds against its own clock (``behind_ms``:
median, p90, max; a process kept off a busy CPU shows here, not in ``latency_ms``), the CPU time it used
since the previous record (``cpu_ms``) and the agent's protocol counters, so that a process killed with SIGKILL has
still reported every step it finished. A step answered provisionally whose window then converged in
the background, or answered again without a member a later window excluded (:mod:`agents.runtime`,
:mod:`agents.exclusion_revisions`), is written again, converged, with ``revised_after_s`` (seconds
after its first record) and ``revised_because`` (``"background"`` or ``"excluded"``); one whose
background window ended unconverged but placed more from the forms it then held is written again
unconverged, ``revised_because: "more_forms"``. A later line of a step replaces the earlier one.

- **a late start**: a process that starts after its START first asks its peers for the run's clock
  (:class:`PeerClock`) and follows the START two of them agree on, from the step under way.
"""

from __future__ import annotations

import dataclasses
import json
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from agents.assembly import AgentConfig, AssemblyAgent
from agents.runtime import AgentHost, LocalAgent, WindowRule
from decentral.errors import InputError
from decentral.observations import Estimate, EstimateStep, ObservationLog, PlanarPose
from decentral.unplaced import count_reasons
from protocols.messages import BROADCAST, Heartbeat
from protocols.transport import Transport
from sims.io.log_json import poses_to_dict
from sims.runners.admm_run import own_step
from sims.runners.run_status import placed_steps, run_status
from sims.runners.start_clock import StartClock

__all__ = ["Pace", "PeerClock", "AgentRun", "run_agent", "step_period", "rounds_per_step", "process_agent_config", "poses_of"]


@dataclass(frozen=True)
class Pace:
    """When a process runs its steps and rounds (wall-clock seconds).

    Attributes
    ----------
    start : float
        Wall time (``time.time()``) of the log's first step; every process of a run gets the same.
    rate : float
        Log seconds per wall second (1: the log's timestamps; 4: four times faster).
    round_period : float
        Wall seconds per ADMM round.
    linger : float
        Wall seconds the agent keeps answering after its last step.
    """

    start: float
    rate: float = 1.0
    round_period: float = 0.01
    linger: float = 1.0

    def __post_init__(self) -> None:
        if not (np.isfinite(self.rate) and self.rate > 0):
            raise InputError(f"must be > 0, got {self.rate!r}", field="--rate")
        if not (np.isfinite(self.round_period) and self.round_period > 0):
            raise InputError(f"must be > 0, got {self.round_period!r}", field="--round-period")

    def due(self, log: ObservationLog, k: int) -> float:
        """Wall time at which step ``k`` of ``log`` comes."""
        return self.start + (log.steps[k].t - log.steps[0].t) / self.rate

    def half(self, now: float) -> int:
        """Index of the half round under way at wall time ``now`` (negative before the start)."""
        return int(np.floor((now - self.start) / (self.round_period / 2) + 1e-6))  # (a step due on a boundary)


class PeerClock:
    """When the peers' round clock started, from the frames that arrive (``sent_at - round * round_period``).

    Every process of a run counts rounds from the same START, so each frame tells its sender's START
    (clocks synchronized, as START itself assumes). :meth:`start` answers once two different senders
    agree within a round period (one member alone cannot move it), with the later of their values (a
    process running behind its clock only makes its value later).

    Examples
    --------
    >>> from types import SimpleNamespace as N
    >>> clock = PeerClock(round_period=0.1)
    >>> clock.observe([N(message=N(sender="A0", round=10), sent_at=11.0),
    ...                N(message=N(sender="A1", round=20), sent_at=12.05)])
    >>> clock.start()
    10.05
    """

    def __init__(self, round_period: float, senders: int = 2):
        self.round_period, self.senders = float(round_period), int(senders)
        self._seen: dict[str, float] = {}

    def observe(self, deliveries) -> None:
        """Take the arrivals of one poll."""
        for d in deliveries:
            r = getattr(d.message, "round", 0)
            if r > 0 and np.isfinite(d.sent_at):
                self._seen[d.message.sender] = d.sent_at - r * self.round_period

    def start(self) -> float | None:
        """The peers' START once ``senders`` of them agree within a round period, else ``None``."""
        values = sorted(self._seen.values())
        for i in range(len(values) - self.senders + 1):
            if values[i + self.senders - 1] - values[i] <= self.round_period:
                return values[i + self.senders - 1]
        return None

    def reset(self) -> None:
        """Forget what was observed (after adopting a START)."""
        self._seen.clear()


@dataclass
class AgentRun:
    """What one agent process produced.

    Attributes
    ----------
    estimate : Estimate
        Its own estimates (relative to itself) of the steps it ran.
    steps : list of dict
        The stream records, one per finished step.
    heard : set of str
        Assemblies from which a frame arrived.
    stats : dict
        Transport counts, rejections, rounds and what it missed.
    """

    estimate: Estimate
    steps: list = field(default_factory=list)
    heard: set = field(default_factory=set)
    stats: dict = field(default_factory=dict)


def step_period(log: ObservationLog) -> float:
    """Median log seconds between two steps (1 s for a one-step log)."""
    t = np.array([s.t for s in log.steps])
    return float(np.median(np.diff(t))) if len(t) > 1 else 1.0


def rounds_per_step(log: ObservationLog, rate: float, round_period: float) -> int:
    """Rounds between two sensor steps at this pace: the window's round budget."""
    return max(2, int(step_period(log) / rate / round_period))


def process_agent_config(part: ObservationLog, name: str, reference: str, window: int, rate: float,
                         round_period: float, aggregation: str = "tree") -> AgentConfig:
    """The configuration of agent ``name`` running its ``part`` at this pace (``aggregation``: how a window's
    forms travel, :class:`agents.assembly.AgentConfig`).

    Its waits are bounded by the rounds between two steps (:meth:`agents.runtime.WindowRule.share_timeout`).
    """
    rule = WindowRule(budget=rounds_per_step(part, rate, round_period))
    return AgentConfig(name=name, assemblies=tuple(part.assemblies), reference=reference,
                       cameras=tuple(part.cameras.values()), node_radius=part.node_radius, window=window,
                       share_timeout=rule.share_timeout(AgentConfig.share_timeout), aggregation=aggregation)


def _counts(transport: Transport, name: str, kinds: bool = False) -> dict:
    """What ``name`` sent (messages, bytes; with ``kinds``, per message kind too), refused and dropped so far."""
    stats = transport.stats()
    mine = stats.per_sender.get(name)
    out = {
        "messages": int(mine.sent) if mine is not None else 0,
        "bytes": int(mine.bytes_sent) if mine is not None else 0,
        "rejected": dict(getattr(stats, "rejected", {}) or {}),
        "dropped": dict(stats.drop_reasons),
    }
    if kinds:  # the transport carries this agent's messages only
        out["per_kind"] = {kind: (int(c.sent), int(c.bytes_sent)) for kind, c in sorted(stats.per_kind.items())}
    return out


def run_agent(part: ObservationLog, name: str, transport: Transport, config: AgentConfig, pace: Pace,
              stream=None, clock: Callable[[], float] = time.time,
              wait: Callable[[float], None] | None = None) -> AgentRun:
    """Run agent ``name`` over its ``part`` of a log on ``transport`` at ``pace``; return what it estimated.

    Parameters
    ----------
    part : ObservationLog
        The agent's part (:mod:`sims.runners.parts`): its own sensors only.
    name : str
        Its assembly.
    transport : Transport
        A transport this agent is attached to (sends and polls as ``name``).
    config : AgentConfig
        The agent's configuration (``config.name == name``).
    pace : Pace
        Start time, rate, round period, linger.
    stream : file-like, optional
        Where each finished step is appended as a JSON line (flushed at once).
    clock : callable
        Wall clock (``time.time``).
    wait : callable, optional
        ``wait(seconds)``: block until then or until a frame arrives (default: ``time.sleep``).
    """
    wait = wait or time.sleep
    per_step = step_period(part) / pace.rate
    budget = rounds_per_step(part, pace.rate, pace.round_period)
    local = LocalAgent(AssemblyAgent(config), WindowRule(budget=budget))
    heard: set[str] = set()
    told = pace.start
    start_clock = StartClock(pace.round_period)  # peers' starts from their round numbers (sims.runners.start_clock)

    clocks = PeerClock(pace.round_period)

    answered: dict[str, float] = {}
    latencies: list[float] = []  # sent_at to arrival of the frames of the current window (s)
    behind: list[float] = []  # how late each half round of the current window ran against its due time (s)
    behind_all: list[float] = []

    class _Listening:  # records who was heard and when the peers' rounds started, then hands the frames on
        def poll(self, agent, now):
            arrivals = transport.poll(agent, now)
            heard.update(d.message.sender for d in arrivals)
            clocks.observe(arrivals)
            latencies.extend(d.latency for d in arrivals)
            for d in arrivals:
                if d.message.round > 0:  # (a round-0 heartbeat asks for the clock: it tells no start)
                    start_clock.heard(d.message.sender, d.message.round, d.sent_at, told - start_clock.moved)
                # a peer that (re)started asks for the run's clock with a round-0 heartbeat: answer with this round
                m = d.message
                if (isinstance(m, Heartbeat) and m.round == 0 and current is not None
                        and now - answered.get(m.sender, -1e9) > pace.round_period):
                    answered[m.sender] = now
                    transport.send(Heartbeat(sender=name, receiver=m.sender, round=max(1, pace.half(now) // 2),
                                             t=now), now)
            return arrivals

        def send(self, message, now):
            transport.send(message, now)

    host = AgentHost(local, _Listening())
    n = len(part.steps)
    now = clock()
    k = first = done_half = 0
    current: int | None = None

    def resume_under_way(now: float) -> None:
        """Go on from the step under way at ``now`` on the current clock (steps that went by are never run) and
        from the half round due then; before the first step, that step is the first."""
        nonlocal k, first, done_half
        while k + 1 < n and pace.due(part, k + 1) <= now:
            k += 1
        if current is None:
            first = k
        done_half = max(pace.half(now), 0) - 1  # half rounds count from the start (0), or from now when late

    resume_under_way(now)  # a late start (a restart) begins with the step under way
    records: list[dict] = []
    max_behind, lagged = 20, 0
    began, took = now, None
    cpu_at = time.process_time()
    over = False  # the last step's window has ended (its next step would be due): LocalAgent.end_of_log
    background_tail = False  # ... and went on in the background

    def run_end() -> float:
        """When the process stops: ``linger`` after the last step, and not before the last window had its step
        period (and, if it went on in the background, one more)."""
        return pace.due(part, n - 1) + max(pace.linger, per_step * (2 if background_tail else 1))

    end = run_end()

    def close(step: int) -> None:
        nonlocal cpu_at
        local.end_window()
        cpu_now = time.process_time()
        cpu_ms, cpu_at = round((cpu_now - cpu_at) * 1e3, 1), cpu_now
        poses = poses_to_dict(dict(sorted(local.window_estimate.items())))
        record = {"step": step, "t": part.steps[step].t, "poses": poses, "unplaced": dict(local.window_unplaced),
                  "converged": local.converged,
                  # a converged window whose forms lacked these agents' (given up on as down): the others' data only
                  "without": list(getattr(local.agent, "without", ())) if local.converged else [],
                  "rounds": local.rounds, "window_seconds": took, "counts": _counts(transport, name), "heard": sorted(heard),
                  "latency_ms": _quantiles(latencies), "behind_ms": _quantiles(behind), "lagged": lagged,
                  "cpu_ms": cpu_ms,
                  "excluded": list(getattr(local.agent, "excluded", ())),
                  "suspects": list(getattr(local.agent, "suspects", ())), "clock": start_clock.report(),
                  "counters": {k: int(v) for k, v in local.agent.counters.items()}}  # (to trace a wrong window)
        latencies.clear()
        if record["behind_ms"] and step != first:  # a process starved of the CPU shares its next windows by
            # broadcast (AssemblyAgent.ran_late: the record's p90); not judged on its first window (a cold start:
            # every agent solves it all)
            local.agent.ran_late(record["behind_ms"][1] / 1e3 / pace.round_period)
        behind_all.extend(behind)
        behind.clear()
        record["closed_at"] = clock()
        records.append(record)
        write(record)

    def write(record: dict) -> None:
        if stream is not None:
            stream.write(json.dumps(record) + "\n")
            stream.flush()

    def revise() -> None:
        """Windows that converged in the background (or ended with more forms) replace their steps' provisional
        records (and are streamed again: a later record of a step replaces the earlier one)."""
        for rev in local.take_revisions():
            at = next((i for i, r in enumerate(records) if r["step"] == rev.step), None)
            if at is None:
                continue
            records[at] = dict(records[at], poses=poses_to_dict(dict(sorted(rev.poses.items()))),
                               unplaced=dict(rev.unplaced), converged=rev.converged, rounds=rev.rounds, without=list(rev.without),
                               revised_after_s=round(clock() - records[at]["closed_at"], 4), revised_because=rev.reason)
            write(records[at])

    adopted = []  # (wall time, the START given, the peers' START adopted)
    # started after its START (a restart, a late start): first listen until two peers tell their clock (at most
    # a few steps), so that a START that is not the peers' is noticed before it runs a step of the wrong time
    listen_until = now + max(4 * per_step, 1.0) if now > pace.start + per_step / 2 else now
    asked, caught_up = -1e9, False
    while True:
        now = clock()
        listening = current is None and (now < pace.start or (now < listen_until and clocks.start() is None))
        if listening:
            # before this agent's first step: listen, so that a START later than the peers' is noticed
            _Listening().poll(name, now)  # (what arrives now belongs to windows it cannot join yet)
            if now >= asked + 0.1:
                transport.send(Heartbeat(sender=name, receiver=BROADCAST, round=0, t=now), now)  # what is the clock?
                asked = now
        elif current is None and not caught_up:
            caught_up = True
            resume_under_way(now)  # listened past some steps: begin with the step under way
        peers_start = clocks.start()
        if peers_start is not None and peers_start < pace.start - per_step / 2:
            # the peers started earlier (a restart given a fresh START): run on their clock from the step under way
            adopted.append((now, pace.start, peers_start))
            pace = dataclasses.replace(pace, start=peers_start)
            # one record of how far this agent's start moved: the skew report (stats['clock']) says so too
            start_clock.moved = max(start_clock.moved, told - peers_start)
            clocks.reset()
            listen_until = now
            resume_under_way(now)
            end = run_end()
        if told - start_clock.follow() != pace.start:  # a peer started earlier: follow its start
            earlier = pace.start - (told - start_clock.moved)
            pace = dataclasses.replace(pace, start=told - start_clock.moved)
            end = run_end()
            if earlier > per_step / 2:  # steps went by on the peers' clock: never run them back to back (a replay)
                resume_under_way(now)
        if k < n and now >= pace.due(part, k) and not listening:
            if current is not None:
                close(current)
            host.on_step(own_step(part, name, k), now, max(0, pace.half(now)) // 2)
            current, k = k, k + 1
            began, took = now, None
        if k >= n and current is not None and not over and now >= pace.due(part, n - 1) + per_step:
            close(current)  # the last window ends when its next step would be due, like every other
            local.end_of_log()
            revise()
            over, background_tail = True, local.waiting_in_background
            end = run_end()
        h = pace.half(now)
        if h > done_half and h >= 0 and current is not None:
            # every half round in order, late ones back to back (skipping a phase would break the protocol's
            # alternation); a process more than `max_behind` halves late jumps to the next round's phase 0
            if h - (done_half + 1) > max_behind:
                done_half = h - 1 if h % 2 == 0 else h  # resume at a phase 0: now, or at the next half round
                lagged += 1
            nxt = done_half + 1
            if nxt <= h:
                behind.append(now - (pace.start + nxt * pace.round_period / 2))
                host.half_round(now, nxt // 2, nxt % 2)
                revise()
                done_half = nxt
                if took is None and local.done:
                    took = clock() - began  # wall time of the window, by the agent's own rule
                if done_half < h and not (k >= n and now >= end):
                    continue  # still behind: no waiting (unless the run is over: a process kept off the CPU for
                    # good would otherwise run half rounds back to back past its end until it is killed)
        if k >= n and now >= end:
            break
        next_half = pace.start + (done_half + 1) * pace.round_period / 2
        next_step = pace.due(part, k) if k < n else end
        if listening:  # before the first step: poll again soon (or at the START)
            wait(max(0.0, min(clock() + 0.02, pace.start) - clock()) if clock() < pace.start else 0.02)
            continue
        wait(max(0.0, min(next_half, next_step) - clock()))
    if current is not None and not over:
        close(current)
    local.end_background()  # the last window's background window, if it is still at work, ends here
    revise()
    names = part.assemblies
    steps = tuple(EstimateStep(r["t"], poses_of(r["poses"]), r["unplaced"]) for r in records)
    final = _counts(transport, name, kinds=True)
    unplaced = count_reasons(step.unplaced for step in steps)
    # converged steps whose window lacked some agents' forms (given up on as down): the others' data only
    without = [{"step": r["step"], "without": r["without"]} for r in records if r["converged"] and r.get("without")]
    # steps answered provisionally whose window converged in the background (or ended with more forms), and how long
    # after the answer
    revised = [{"step": r["step"], "after_s": r["revised_after_s"], "reason": r.get("revised_because", "background")}
               for r in records if "revised_after_s" in r]
    status, status_counts = run_status([r["converged"] for r in records], placed_steps(steps), unplaced,
                                       not_run=n - len(records), revised_because=[r["reason"] for r in revised],
                                       without=len(without))
    stats = {
        "unplaced": unplaced,
        "status": status,
        "status_counts": status_counts,
        "estimator": "consensus-admm",
        "mode": "process",
        "agent": name,
        "first_step": first,
        "skipped": first,  # steps that were over when it started (a late start or a restart)
        "adopted_start": [{"at": a, "given": g, "peers": p} for a, g, p in adopted],
        "processes": 1,
        "messages": {"total": final["messages"], "per_agent": {name: final["messages"]},
                     "per_kind": {kind: n for kind, (n, _) in final["per_kind"].items()}},
        "bytes": {"total": final["bytes"], "per_agent": {name: final["bytes"]},
                  "per_kind": {kind: b for kind, (_, b) in final["per_kind"].items()}},
        "rejected": final["rejected"],
        "dropped": final["dropped"],
        "rounds_per_step": [r["rounds"] for r in records],
        "converged_per_step": [r["converged"] for r in records],
        "revised": revised,
        "converged_without": without,
        "missing": sorted(a for a in names if a != name and a not in heard),
        "round_period": pace.round_period,
        "aggregation": config.aggregation,
        "lagged": lagged,  # times the process fell more than 20 half rounds behind and jumped
        # how late the half rounds ran against the process's own clock over the run (median, p90, max, ms)
        "behind_ms": _quantiles(behind_all),
        # CPU time of the whole process (start-up included) and of each step (median, max), ms
        "cpu_ms": {"total": round(time.process_time() * 1e3, 1),
                   "per_step": median_max([r["cpu_ms"] for r in records])},
        "rate": pace.rate,
        "clock": start_clock.report(),  # peers' start offsets, and how far this agent's start was moved
    }
    est = Estimate(name, steps, stats)
    return AgentRun(est, records, heard, stats)


def median_max(values: list[float]) -> list[float] | None:
    """``[median, max]`` of ``values`` (rounded to 0.1), ``None`` without any."""
    return [round(float(np.median(values)), 1), round(float(max(values)), 1)] if values else None


def _quantiles(latencies: list[float]) -> list[float] | None:
    """``[median, p90, max]`` of ``latencies`` (s) in ms, ``None`` without any."""
    if not latencies:
        return None
    q = np.quantile(np.asarray(latencies, float), [0.5, 0.9, 1.0]) * 1e3
    return [round(float(x), 3) for x in q]


def poses_of(raw: dict) -> dict[str, PlanarPose]:
    """A stream record's ``poses`` as :class:`PlanarPose` objects."""
    return {a: PlanarPose(np.array(v["p"], float), float(v["theta"])) for a, v in raw.items()}
