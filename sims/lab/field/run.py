"""A whole log as one ``decentral agent`` process per network namespace, behind impaired links.

:func:`run_field` is :func:`sims.runners.launch.launch` on a field (:class:`sims.lab.field.netns.Field`) instead of
the loopback interface: each agent listens on its own namespace's address, and every other agent
reaches it through the link's relay in the hub (:mod:`sims.lab.field.proxy`: delay, jitter, rate) and the
hub's kernel (packet loss); optionally with busy processes on the same cores
(:class:`sims.lab.field.starve.Busy`). The estimate is composed as ``launch`` composes it.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from decentral.errors import DecentralError
from decentral.observations import ObservationLog
from sims.lab.field.netns import Field
from sims.lab.field.starve import Busy
from sims.runners.launch import LaunchConfig, LaunchResult, _Children, _compose, _die_with_parent, _read_records, _wait_ready
from sims.runners.parts import split_log, write_part

__all__ = ["FieldConfig", "run_field"]

_AGENT_PORT = 7000
_LINK_PORT = 20000


@dataclass(frozen=True)
class FieldConfig:
    """The field's links and load (the agents' options are a :class:`sims.runners.launch.LaunchConfig`).

    Attributes
    ----------
    delay : float
        One-way delay of every link (s).
    jitter : float
        Relative jitter: each datagram (or stream chunk) waits ``delay * (1 + jitter * u)``, ``u`` in [-1, 1].
    loss : float
        Share of packets lost on every link: datagrams by the link relays, each link from its own seeded
        stream (:mod:`sims.lab.field.proxy`), TCP packets by the hub's kernel (:class:`sims.lab.field.netns.Field`).
    rate : float, optional
        Bytes per second of every link (``None``: unlimited).
    busy_per_core : int
        Spinning processes per core while the agents run.
    seed : int
        Seed of the links' delays and of their datagrams' loss.
    start_margin : float
        Seconds between the moment every agent listens and the log's first step.
    fresh_restart : bool
        Give a restarted agent a START of its own (now + ``start_margin``, as a person restarting it by
        hand would) instead of the run's.
    """

    delay: float = 0.0
    jitter: float = 0.2
    loss: float = 0.0
    rate: float | None = None
    busy_per_core: int = 0
    seed: int = 0
    start_margin: float = 0.5
    fresh_restart: bool = False


#: the link relays' niceness: they stand for the radio, so the busy processes that starve the agents must not
#: starve them too (at equal priority, one relay process for every link of an 8-ring got a thirteenth of a core
#: with two busy processes per core, and its queues counted as link latency)
RELAY_NICE = -10


def _relay_preexec() -> None:  # runs in the relay between fork and exec
    _die_with_parent()
    try:
        os.setpriority(os.PRIO_PROCESS, 0, RELAY_NICE)
    except OSError:
        pass  # not allowed (not root): the relay runs at the agents' priority, and the report's latency shows it


def run_field(log: ObservationLog, launch: LaunchConfig = LaunchConfig(), fieldc: FieldConfig = FieldConfig(),
              workdir: str | os.PathLike | None = None, python: str | None = None) -> LaunchResult:
    """Run ``log`` as one agent process per namespace; return the reference agent's estimate.

    Parameters
    ----------
    log : ObservationLog
        The whole log (each agent gets its own part).
    launch : LaunchConfig
        The agents' options (window, pace, transport, crashes); ``loss`` there is receive-side loss on
        top of the field's.
    fieldc : FieldConfig
        Links and load.
    workdir : path, optional
        Keys, peers files, parts, streams (default: a temporary folder, removed afterwards).
    """
    if workdir is None:
        with tempfile.TemporaryDirectory(prefix="decentral-field-") as tmp:
            return _run(log, launch, fieldc, Path(tmp), python or sys.executable)
    return _run(log, launch, fieldc, Path(workdir), python or sys.executable)


def _run(log, config: LaunchConfig, fc: FieldConfig, work: Path, python: str) -> LaunchResult:
    from protocols.auth import new_private_key, public_key_bytes
    from protocols.peers import Peer, peers_json, private_key_json
    from sims.runners.agent_run import step_period
    from sims.io.atomic import write_json_atomic

    names = tuple(log.assemblies)
    n = len(names)
    reference = config.reference or names[0]
    work.mkdir(parents=True, exist_ok=True)
    keys = {name: new_private_key() for name in names}
    with Field(n, loss=fc.loss) as net, _Children() as children:
        port = lambda a, b: _LINK_PORT + a * n + b  # noqa: E731
        links = []
        for a in range(n):
            table = {}
            for b in range(n):
                if a == b:
                    address = f"tcp://{net.ip(a)}:{_AGENT_PORT}"
                else:
                    address = f"tcp://{net.hub_ip}:{port(a, b)}"
                    links.append({"name": f"{names[a]}->{names[b]}", "port": port(a, b), "to": [net.ip(b), _AGENT_PORT],
                                  "delay": fc.delay, "jitter": fc.jitter, "rate": fc.rate, "loss": fc.loss,
                                  "seed": fc.seed * 7919 + a * n + b})
                table[names[b]] = Peer(names[b], address, public_key_bytes(keys[names[b]]))
            write_json_atomic(work / f"{names[a]}.peers.json", peers_json(table))
        (work / "proxy.json").write_text(json.dumps({"host": net.hub_ip, "links": links}))
        for name, part in split_log(log).items():
            write_json_atomic(work / f"{name}.key", private_key_json(name, keys[name]))
            os.chmod(work / f"{name}.key", 0o600)
            write_part(work / f"{name}.part.json", part, name)
        env = dict(os.environ, PYTHONUNBUFFERED="1", OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1",
                   MKL_NUM_THREADS="1", PYTHONPATH=os.pathsep.join(filter(None, [str(Path(__file__).resolve().parents[2]),
                                                                                  os.environ.get("PYTHONPATH")])))
        with open(work / "proxy.err", "w") as err:
            relay = subprocess.Popen(net.exec(net.hub) + [python, "-m", "sims.lab.field.proxy", str(work / "proxy.json")],
                                     stdout=subprocess.PIPE, stderr=err, stdin=subprocess.DEVNULL, text=True,
                                     preexec_fn=_relay_preexec, env=env)
        children.procs.append(relay)
        if relay.stdout.readline().strip() != "ready":
            raise DecentralError(f"link relay did not start: {(work / 'proxy.err').read_text().strip()[-300:]}")
        incarnations = {name: 0 for name in names}
        started = []

        def start_one(i: int, start: str) -> subprocess.Popen:
            name = names[i]
            argv = net.exec(net.ns(i)) + [
                python, "-m", "sims.cli.main", "agent", name, "--log", str(work / f"{name}.part.json"),
                "--peers", str(work / f"{name}.peers.json"), "--key", str(work / f"{name}.key"),
                "--stream", str(work / f"{name}.{incarnations[name]}.jsonl"), "--start", start,
                "-o", str(work / f"{name}.{incarnations[name]}.est.json"),
                "--reference", reference, "--window", str(config.window), "--loss", repr(config.loss),
                "--seed", str(config.seed), "--rate", repr(config.rate), "--round-period", repr(config.round_period),
                *(("--transport", config.transport) if config.transport else ()),
                "--aggregation", config.aggregation, *config.extra_args]
            (work / f"{name}.{incarnations[name]}.jsonl").unlink(missing_ok=True)  # (a workdir used before)
            with open(work / f"{name}.{incarnations[name]}.err", "w") as err:
                proc = subprocess.Popen(argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=err,
                                        preexec_fn=_die_with_parent, text=True, bufsize=1, env=env)
            children.procs.append(proc)
            started.append((name, incarnations[name], proc))
            return proc

        busy = Busy(fc.busy_per_core) if fc.busy_per_core else None
        if busy:
            busy.__enter__()
        try:
            procs = {name: start_one(i, "-") for i, name in enumerate(names)}
            began = time.monotonic()
            _wait_ready(procs, config.ready_timeout, work)
            start = time.time() + fc.start_margin
            for proc in procs.values():
                proc.stdin.write(f"{start!r}\n")
                proc.stdin.flush()
            t0 = log.steps[0].t
            due = lambda k: start + (log.steps[k].t - t0) / config.rate  # noqa: E731
            events = []
            for plan in config.crashes:
                events.append((due(plan.step), "kill", plan.name))
                if plan.down is not None and plan.step + plan.down < len(log.steps):
                    events.append((due(plan.step + plan.down), "start", plan.name))
            events.sort()
            end = due(len(log.steps) - 1) + max(1.0, step_period(log) / config.rate) + 30.0
            timed_out = False
            while True:
                now = time.time()
                while events and events[0][0] <= now:
                    _, what, name = events.pop(0)
                    if what == "kill" and procs[name].poll() is None:
                        procs[name].kill()
                        procs[name].wait()
                    elif what == "start":
                        incarnations[name] += 1
                        again = time.time() + fc.start_margin if fc.fresh_restart else start
                        procs[name] = start_one(names.index(name), repr(again))
                if not any(p.poll() is None for p in procs.values()) and not events:
                    break
                if (config.timeout is not None and time.monotonic() - began > config.timeout) or now > end:
                    timed_out = True
                    break
                time.sleep(0.05)
        finally:
            if busy:
                busy.__exit__(None, None, None)
    records = {name: [_read_records(work / f"{name}.{i}.jsonl") for i in range(incarnations[name] + 1)]
               for name in names}
    failures = {}
    for name, i, proc in started:
        if proc.returncode not in (0, -9, None):
            text = (work / f"{name}.{i}.err").read_text().strip().splitlines()
            failures[f"{name}.{i}"] = text[-1] if text else f"exit status {proc.returncode}"
    est = _compose(log, reference, records, config, incarnations, timed_out, failures)
    est.stats.update({"mode": "field", "field": {"delay": fc.delay, "jitter": fc.jitter, "loss": fc.loss,
                                                 "rate": fc.rate, "busy_per_core": fc.busy_per_core,
                                                 "seed": fc.seed}})
    return LaunchResult(est, records, timed_out)
