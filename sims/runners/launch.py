"""Run a whole log as one operating-system process per assembly on the loopback interface.

:func:`launch` makes a key per agent and a peers file (free TCP ports on 127.0.0.1) in a temporary
folder, splits the log into the agents' parts (:mod:`sims.runners.parts`), starts one ``decentral agent``
per assembly, tells them all the same start time once every one is listening, kills and restarts
agents on the ``--crash`` schedule, and composes the reference agent's ``decentral.estimate/1`` from
what its processes streamed (a killed process has still reported every step it finished).

No process it started outlives it: children die with it (``PR_SET_PDEATHSIG`` = SIGKILL, set in the
child before it runs), and launch kills every child when it returns, raises, or gets SIGINT/SIGTERM
(signal handlers, ``atexit`` and ``finally``).

No key outlives it either. Without a work folder the private keys never touch a disk: each agent
gets its key as one line on its stdin (``decentral agent --key -``). The temporary folder (parts,
peers file, streams) is removed on return, on error and on SIGINT/SIGTERM, and a small janitor
process removes it when launch dies by SIGKILL: it waits for the end of a pipe only launch holds.
With ``--workdir`` the key files are created with mode 0600 (never readable by others, not even
for an instant) and kept, as asked.
"""

from __future__ import annotations

import atexit
import ctypes
import json
import os
import re
import select
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from decentral.errors import DecentralError, InputError
from decentral.observations import Estimate, EstimateStep, ObservationLog
from decentral.unplaced import count_reasons
from sims.runners.agent_run import median_max, poses_of, step_period
from sims.runners.parts import split_log, write_part
from sims.runners.run_status import run_status

__all__ = ["CrashPlan", "LaunchConfig", "LaunchResult", "parse_crash", "launch"]

_CRASH = re.compile(r"^([^@]+)@([0-9]+)(?:\+([0-9]+))?$")


@dataclass(frozen=True)
class CrashPlan:
    """``NAME@STEP[+DOWN]``: SIGKILL agent ``name`` when the log reaches ``step``; a fresh process
    ``down`` steps later (``None``: never)."""

    name: str
    step: int
    down: int | None = None


def parse_crash(text: str) -> CrashPlan:
    """Parse ``NAME@STEP[+DOWN]`` (``A2@40+10``)."""
    match = _CRASH.match(text.strip())
    if not match:
        raise InputError(f"expected NAME@STEP[+DOWN], got {text!r}", field="--crash")
    name, step, down = match.groups()
    return CrashPlan(name, int(step), None if down is None else int(down))


@dataclass(frozen=True)
class LaunchConfig:
    """Options of :func:`launch` (``decentral launch``).

    Attributes
    ----------
    window : int
        Sliding-window length K.
    reference : str, optional
        The assembly whose estimate is written (default: the first listed).
    loss : float
        Probability that a frame is dropped at the receiving side.
    seed : int
        Seed of the receive-side losses (every process gets it; each link has its own stream).
    crashes : tuple of CrashPlan
        Kill/restart schedule.
    timeout : float, optional
        Wall seconds after which every process is killed and what was gathered is written.
    rate : float
        Log seconds per wall second (1: the log's pace).
    round_period : float
        Wall seconds per ADMM round.
    absent : tuple of str
        Agents that are never started (a peer that never comes up).
    ready_timeout : float
        Wall seconds to wait for every process to listen.
    transport : {"zmq", "udp"}, optional
        The agents' transport (default: ``decentral agent``'s).
    aggregation : {"tree", "broadcast"}
        How a window's forms travel between the agents (``decentral agent --aggregation``).
    extra_args : tuple of str
        More ``decentral agent`` options given to every agent.
    start_offsets : tuple of (str, float)
        Seconds added to the start time an agent is told (skewed clocks, for testing; default none).
    """

    window: int = 5
    reference: str | None = None
    loss: float = 0.0
    seed: int = 0
    crashes: tuple[CrashPlan, ...] = ()
    timeout: float | None = None
    rate: float = 1.0
    round_period: float = 0.01
    absent: tuple[str, ...] = ()
    ready_timeout: float = 120.0
    transport: str | None = None
    aggregation: str = "tree"
    extra_args: tuple[str, ...] = ()
    start_offsets: tuple[tuple[str, float], ...] = ()


@dataclass
class LaunchResult:
    """The reference agent's estimate and every agent's stream records (name -> list of incarnations)."""

    estimate: Estimate
    records: dict = field(default_factory=dict)
    timed_out: bool = False


def _free_ports(n: int) -> list[int]:
    """``n`` ports free for TCP and for UDP on 127.0.0.1 (the agents use one or the other, ``--transport``)."""
    socks, ports = [], []
    try:
        while len(ports) < n:
            s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            s.bind(("127.0.0.1", 0))
            socks.append(s)
            u = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            socks.append(u)
            try:
                u.bind(("127.0.0.1", s.getsockname()[1]))
            except OSError:
                continue  # that port is taken for UDP: try another
            ports.append(s.getsockname()[1])
    finally:
        for s in socks:
            s.close()
    return ports


#: the janitor: wait for launch's end of the pipe to close (launch exited or was killed), then remove the folder
_JANITOR = """
import os, shutil, signal, sys, time
signal.signal(signal.SIGINT, signal.SIG_IGN)
signal.signal(signal.SIGTERM, signal.SIG_IGN)
while os.read(0, 4096):
    pass
for _ in range(50):  # agents are being SIGKILLed by the kernel and may still hold files open for a moment
    shutil.rmtree(sys.argv[1], ignore_errors=True)
    if not os.path.exists(sys.argv[1]):
        break
    time.sleep(0.05)
"""


class _Janitor:
    """Removes ``folder`` when this process ends, however it ends (SIGKILL included)."""

    def __init__(self, folder: Path, python: str):
        self.folder = folder
        self.proc = subprocess.Popen([python, "-c", _JANITOR, str(folder)], stdin=subprocess.PIPE,
                                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)

    def close(self) -> None:
        """Remove the folder now and let the janitor go."""
        shutil.rmtree(self.folder, ignore_errors=True)
        try:
            self.proc.stdin.close()
        except OSError:
            pass
        try:
            self.proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


def _die_with_parent() -> None:  # runs in the child between fork and exec
    try:
        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except OSError:
        pass  # not Linux: launch's own handlers still kill the children


class _Children:
    """Every process launch started; killed on exit, error, SIGINT and SIGTERM."""

    def __init__(self):
        self.procs: list[subprocess.Popen] = []
        self._old = {}

    def __enter__(self):
        atexit.register(self.kill_all)
        for sig in (signal.SIGINT, signal.SIGTERM):
            try:
                self._old[sig] = signal.signal(sig, self._on_signal)
            except ValueError:  # not the main thread: atexit and finally still apply
                pass
        return self

    def _on_signal(self, signum, frame):
        self.kill_all()
        old = self._old.get(signum)
        if callable(old):  # the command's own handler: one line on stderr and its exit status
            old(signum, frame)
        raise KeyboardInterrupt if signum == signal.SIGINT else SystemExit(128 + signum)

    def kill_all(self) -> None:
        for proc in self.procs:
            if proc.poll() is None:
                proc.kill()
        for proc in self.procs:
            try:
                proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                pass
            for pipe in (proc.stdin, proc.stdout):
                try:
                    if pipe is not None:
                        pipe.close()
                except OSError:
                    pass

    def __exit__(self, *exc):
        self.kill_all()
        for sig, old in self._old.items():
            signal.signal(sig, old)
        atexit.unregister(self.kill_all)
        return False


def _read_records(path: Path) -> list[dict]:
    out = []
    if not path.exists():
        return out
    for line in path.read_text().splitlines():
        try:
            out.append(json.loads(line))
        except json.JSONDecodeError:
            break  # a line cut by SIGKILL: the steps before it stand
    return out


def _wait_ready(procs: dict[str, subprocess.Popen], timeout: float, errors: Path) -> None:
    pending = dict(procs)
    deadline = time.monotonic() + timeout
    while pending:
        left = deadline - time.monotonic()
        if left <= 0:
            raise DecentralError(f"agents {sorted(pending)} did not start listening within {timeout:g} s")
        ready, _, _ = select.select([p.stdout for p in pending.values()], [], [], min(left, 1.0))
        for name, proc in list(pending.items()):
            if proc.stdout in ready:
                line = proc.stdout.readline()
                if line.strip() == "ready":
                    del pending[name]
                elif not line:
                    msg = (errors / f"{name}.0.err").read_text().strip().splitlines()
                    raise DecentralError(f"agent {name} exited before listening: {msg[-1] if msg else '?'}")


def launch(log: ObservationLog, config: LaunchConfig = LaunchConfig(), workdir: str | os.PathLike | None = None,
           python: str | None = None) -> LaunchResult:
    """Run ``log`` as one ``decentral agent`` process per assembly; return the reference agent's estimate.

    Parameters
    ----------
    log : ObservationLog
        The whole log (each process gets only its own part).
    config : LaunchConfig
        Options.
    workdir : path, optional
        Where keys, peers file, parts and streams go (default: a temporary folder, removed afterwards).
    python : str, optional
        The interpreter that runs the agents (default: this one).
    """
    names = tuple(log.assemblies)
    reference = config.reference or names[0]
    if reference not in names:
        raise InputError(f"no assembly {reference!r} in the log", field="--reference")
    for plan in config.crashes:
        if plan.name not in names:
            raise InputError(f"no assembly {plan.name!r} in the log", field="--crash")
        if plan.step >= len(log.steps):
            raise InputError(f"step {plan.step} is past the log's last step {len(log.steps) - 1}", field="--crash")
    for name in config.absent:
        if name not in names:
            raise InputError(f"no assembly {name!r} in the log", field="--absent")
    if reference in config.absent:
        raise InputError("the reference agent must run", field="--absent")
    python = python or sys.executable
    if workdir is None:
        tmp = Path(tempfile.mkdtemp(prefix="decentral-launch-"))  # mode 0700
        try:
            janitor = _Janitor(tmp, python)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        try:
            return _launch(log, config, reference, tmp, python, keep_keys=False)
        finally:
            janitor.close()
    return _launch(log, config, reference, Path(workdir), python, keep_keys=True)


def _launch(log: ObservationLog, config: LaunchConfig, reference: str, work: Path, python: str, *,
            keep_keys: bool) -> LaunchResult:
    from protocols.auth import new_private_key, public_key_bytes
    from protocols.peers import Peer, peers_json, private_key_json
    from sims.io.atomic import write_json_atomic

    names = tuple(log.assemblies)
    work.mkdir(parents=True, exist_ok=True)
    ports = _free_ports(len(names))
    keys = {name: new_private_key() for name in names}
    peers = {name: Peer(name, f"tcp://127.0.0.1:{port}", public_key_bytes(keys[name]))
             for name, port in zip(names, ports)}
    write_json_atomic(work / "peers.json", peers_json(peers))
    for name, part in split_log(log).items():
        if keep_keys:  # created 0600 (written to a 0600 temporary file, then renamed)
            write_json_atomic(work / f"{name}.key", private_key_json(name, keys[name]), mode=0o600)
        write_part(work / f"{name}.part.json", part, name)
    key_lines = {name: json.dumps(private_key_json(name, keys[name])) + "\n" for name in names}

    def args(name: str, incarnation: int, start: str) -> list[str]:
        return [python, "-m", "sims.cli.main", "agent", name, "--log", str(work / f"{name}.part.json"),
                "--peers", str(work / "peers.json"), "--key", str(work / f"{name}.key") if keep_keys else "-",
                "--stream", str(work / f"{name}.{incarnation}.jsonl"), "--start", start,
                "--reference", reference, "--window", str(config.window), "--loss", repr(config.loss),
                "--seed", str(config.seed), "--rate", repr(config.rate), "--round-period", repr(config.round_period),
                "-o", str(work / f"{name}.{incarnation}.est.json"),
                *(("--transport", config.transport) if config.transport else ()),
                "--aggregation", config.aggregation, *config.extra_args]

    period = step_period(log) / config.rate
    t_first = log.steps[0].t
    incarnations = {name: 0 for name in names}
    timed_out = False
    running = [n for n in names if n not in config.absent]
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env.setdefault(var, "1")
    started: list[tuple[str, int, subprocess.Popen]] = []
    with _Children() as children:
        def start_one(name: str, start: str) -> subprocess.Popen:
            # the agent appends to its stream: a --workdir used before holds an earlier run's records
            (work / f"{name}.{incarnations[name]}.jsonl").unlink(missing_ok=True)
            err = open(work / f"{name}.{incarnations[name]}.err", "w")
            try:
                proc = subprocess.Popen(args(name, incarnations[name], start), stdin=subprocess.PIPE,
                                        stdout=subprocess.PIPE, stderr=err, preexec_fn=_die_with_parent,
                                        text=True, bufsize=1, env=env)
            finally:
                err.close()
            children.procs.append(proc)
            (work / f"{name}.{incarnations[name]}.pid").write_text(str(proc.pid))
            if not keep_keys:
                try:
                    proc.stdin.write(key_lines[name])  # the key travels on the pipe, never on disk
                    proc.stdin.flush()
                except OSError:
                    pass  # it died already: waiting for it to listen reports why
            started.append((name, incarnations[name], proc))
            return proc

        procs = {name: start_one(name, "-") for name in running}
        began = time.monotonic()
        _wait_ready(procs, config.ready_timeout, work)
        start = time.time() + 0.3
        skew = dict(config.start_offsets)
        for name, proc in procs.items():
            proc.stdin.write(f"{start + skew.get(name, 0.0)!r}\n")
            proc.stdin.flush()
        due = lambda k: start + (log.steps[k].t - t_first) / config.rate  # noqa: E731
        events = []  # (wall time, "kill"/"start", name)
        for plan in config.crashes:
            events.append((due(plan.step), "kill", plan.name))
            if plan.down is not None:
                back = plan.step + plan.down
                if back < len(log.steps):
                    events.append((due(back), "start", plan.name))
        events.sort()
        end = due(len(log.steps) - 1) + max(1.0, period) + 30.0  # agents stop on their own before this
        while True:
            now = time.time()
            while events and events[0][0] <= now:
                _, what, name = events.pop(0)
                if what == "kill" and name in procs and procs[name].poll() is None:
                    procs[name].kill()  # SIGKILL
                    procs[name].wait()
                elif what == "start":
                    incarnations[name] += 1
                    procs[name] = start_one(name, repr(start + skew.get(name, 0.0)))  # fresh: no state carried over
            alive = [p for p in procs.values() if p.poll() is None]
            if not alive and not events:
                break
            if config.timeout is not None and time.monotonic() - began > config.timeout or now > end:
                timed_out = True
                break
            time.sleep(0.05)
    records = {name: [_read_records(work / f"{name}.{i}.jsonl") for i in range(incarnations[name] + 1)]
               for name in names}
    failures = {}  # processes that ended by an error of their own (not by launch's SIGKILL)
    for name, i, proc in started:
        if proc.returncode not in (0, -signal.SIGKILL, None):
            text = (work / f"{name}.{i}.err").read_text().strip().splitlines()
            failures[f"{name}.{i}"] = text[-1] if text else f"exit status {proc.returncode}"
    return LaunchResult(_compose(log, reference, records, config, incarnations, timed_out, failures), records,
                        timed_out)


def _compose(log, reference, records, config, incarnations, timed_out, failures) -> Estimate:
    """The reference's estimate over every step (a step its processes did not finish has no poses)."""
    by_step = {}
    for incarnation in records[reference]:
        for rec in incarnation:
            if "step" in rec:  # (the last line of a process that ended by itself holds its final counts)
                by_step[rec["step"]] = rec  # a later incarnation's record of the same step wins
    # a step the reference's processes did not finish (down, or the run timed out) holds no agreed pose
    not_run = {name: "no_consensus" for name in log.assemblies if name != reference}
    steps = tuple(EstimateStep(s.t, poses_of(by_step[k]["poses"]), by_step[k].get("unplaced", {})) if k in by_step
                  else EstimateStep(s.t, {}, not_run) for k, s in enumerate(log.steps))
    messages, nbytes, rejected = {}, {}, {}
    for name, runs in records.items():
        messages[name] = sum(run[-1]["counts"]["messages"] for run in runs if run)
        nbytes[name] = sum(run[-1]["counts"]["bytes"] for run in runs if run)
        for run in runs:
            if run:
                for reason, n in run[-1]["counts"]["rejected"].items():
                    rejected[reason] = rejected.get(reason, 0) + int(n)
    for reason in ("bad_signature", "replay", "unknown_sender", "malformed"):
        rejected.setdefault(reason, 0)
    unplaced = count_reasons(step.unplaced for step in steps)
    ran = sorted(by_step)
    # converged steps whose window lacked some agents' forms (given up on as down): the others' data only
    without = [{"step": k, "without": by_step[k]["without"]} for k in ran
               if by_step[k]["converged"] and by_step[k].get("without")]
    # the reference's steps answered provisionally whose window converged in the background, or ended with more
    # forms (agents.runtime)
    revised = [{"step": k, "after_s": by_step[k]["revised_after_s"],
                "reason": by_step[k].get("revised_because", "background")} for k in ran if "revised_after_s" in by_step[k]]
    status, status_counts = run_status([bool(by_step[k]["converged"]) for k in ran], [bool(steps[k].poses) for k in ran],
                                       unplaced, not_run=len(log.steps) - len(ran), timed_out=timed_out,
                                       revised_because=[r["reason"] for r in revised], without=len(without))
    heard = set()
    for run in records[reference]:
        if run:
            heard |= set(next((rec.get("heard", []) for rec in reversed(run) if "step" in rec), []))
    stats = {
        "unplaced": unplaced,
        "estimator": "consensus-admm",
        "mode": "processes",
        "window": config.window,
        "loss": config.loss,
        "seed": config.seed,
        "rate": config.rate,
        "round_period": config.round_period,
        "aggregation": config.aggregation,
        "processes": int(sum(1 for n in records if n not in config.absent) + sum(incarnations.values())),
        "restarts": dict(incarnations),
        "messages": {"total": int(sum(messages.values())), "per_agent": messages},
        "bytes": {"total": int(sum(nbytes.values())), "per_agent": nbytes},
        "rejected": rejected,
        "steps_reported": len(set(rec["step"] for run in records[reference] for rec in run if "step" in rec)),
        "converged_per_step": [bool(by_step[k]["converged"]) if k in by_step else False for k in range(len(log.steps))],
        "rounds_per_step": [int(by_step[k]["rounds"]) if k in by_step else 0 for k in range(len(log.steps))],
        "revised": revised,
        "converged_without": without,
        "missing": sorted(n for n in log.assemblies if n != reference and n not in heard),
        # members whose data the others contradicted, left out of the reference's joint solution
        "excluded": sorted({a for run in records[reference] for rec in run for a in rec.get("excluded", ())}),
        "suspects": sorted({a for run in records[reference] for rec in run for a in rec.get("suspects", ())}),
        "absent": list(config.absent),
        # per agent: peers' start offsets from their round numbers, and how far it followed the earliest start
        "clock": {name: next((rec["clock"] for rec in reversed(runs[-1]) if "clock" in rec), {})
                  for name, runs in records.items() if runs and runs[-1]},
        # per agent: how late its half rounds ran against its own clock, the p90 of each step: [median, largest]
        # over its steps (ms); a process kept off a busy CPU shows here, not in the links' latency
        "behind_ms": _per_step(records, lambda rec: rec["behind_ms"][1] if rec.get("behind_ms") else None),
        # per agent: CPU time of each step, [median, largest] over its steps (ms)
        "cpu_ms": _per_step(records, lambda rec: rec.get("cpu_ms")),
        "status": status,
        "status_counts": status_counts,
    }
    if failures:
        stats["agent_errors"] = failures
    return Estimate(reference, steps, stats)


def _per_step(records: dict, value) -> dict[str, list[float]]:
    """Per agent ``[median, largest]`` over its steps' records of ``value(record)`` (records without one skipped)."""
    out = {}
    for name, runs in records.items():
        values = [v for run in runs for rec in run if "step" in rec and (v := value(rec)) is not None]
        if values:
            out[name] = median_max(values)
    return out
