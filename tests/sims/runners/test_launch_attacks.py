"""Real processes under attack: floods at a non-reference member, and frames replayed from an earlier mission.

Each test runs ``launch`` on a 5-assembly log at the pace of the attack reports (``--rate 0.2
--round-period 0.05``, one second of wall time per step) while another process attacks, so they
are marked slow; the floods are bounded in rate and time.
"""

from __future__ import annotations

import json
import multiprocessing
import time
from pathlib import Path

import numpy as np
import pytest

from decentral.estimator import EstimatorConfig, estimate_log
from sims.runners.launch import LaunchConfig, launch
from sims.simulation.scenarios import get_scenario, simulate
from tests.synthetic import without

PACE = dict(rate=0.2, round_period=0.05, transport="zmq")  # the attacker (protocols.testing.attacker) speaks ZeroMQ
GIB = 2**30


def _wait_for_agents(work: Path, n: int, timeout: float = 120.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and not (len(list(work.glob("*.0.jsonl"))) >= n and all(
            p.stat().st_size for p in work.glob("*.0.jsonl"))):
        time.sleep(0.05)


def _flood(work: str, kind: str, rate: float, seconds: float, out: str) -> None:
    """Send forged frames naming A1 (wrong key) at A2: ``small`` at ``rate`` per second, or ``big`` (16 MiB
    each) as fast as one connection takes them; sample every agent's resident memory meanwhile."""
    import zmq

    from protocols.auth import new_private_key, seal
    from protocols.messages import BROADCAST, Heartbeat
    from protocols.peers import load_peers
    from protocols.testing.attacker import record_peak_rss

    workdir = Path(work)
    _wait_for_agents(workdir, 5)
    peers = load_peers(workdir / "peers.json")
    pids = [int(p.read_text()) for p in workdir.glob("*.pid")]
    wrong = new_private_key()
    pad = b"\x00" * (16 * 2**20) if kind == "big" else b""
    frames = [seal(wrong, "A1", 2**63 + i, i, time.time(), Heartbeat(sender="A1", receiver=BROADCAST, round=i,
                                                                    t=0.0).to_bytes() + pad)
              for i in range(512 if kind == "small" else 2)]
    ctx = zmq.Context()
    push = ctx.socket(zmq.PUSH)
    push.setsockopt(zmq.SNDHWM, 100_000 if kind == "small" else 4)
    push.setsockopt(zmq.SNDTIMEO, 100)
    push.connect(peers["A2"].address)
    sent, peak = 0, {}
    t0 = time.monotonic()
    next_sample = t0
    while time.monotonic() < t0 + seconds:
        now = time.monotonic()
        due = int((now - t0) * rate) if kind == "small" else sent + 1
        while sent < due:
            try:
                push.send(frames[sent % len(frames)])
                sent += 1
            except zmq.Again:
                break
        if now >= next_sample:
            next_sample = now + 0.1
            record_peak_rss(pids, peak)
        time.sleep(0.002)
    push.close(linger=0)
    ctx.term()
    Path(out).write_text(json.dumps({"sent": sent, "peak_rss": max(peak.values(), default=0)}))


def _launch_flooded(tmp_path, kind: str, rate: float, steps: int = 12):
    sim = simulate(get_scenario("multi", n_assemblies=5, steps=steps), seed=1)
    central = estimate_log(sim.log, EstimatorConfig(window=5))
    work, report = tmp_path / "work", tmp_path / "flood.json"
    attacker = multiprocessing.get_context("spawn").Process(
        target=_flood, args=(str(work), kind, rate, steps * 1.0, str(report)))
    attacker.start()
    try:
        est = launch(sim.log, LaunchConfig(**PACE), workdir=work).estimate
    finally:
        attacker.join(timeout=120)
        if attacker.is_alive():
            attacker.kill()
    return sim, central, est, json.loads(report.read_text())


def _gaps_on_converged(central, est, same_set: bool = True) -> list[float]:
    """Largest position gap (m) to the centralized estimate on each step the estimate reports converged; the
    assemblies placed must be the centralized estimate's (``same_set``) or some of them."""
    gaps = []
    for c, e, ok in zip(central.steps, est.steps, est.stats["converged_per_step"]):
        if ok:
            if same_set:
                assert set(e.poses) == set(c.poses), (sorted(e.poses), sorted(c.poses))
            assert set(e.poses) <= set(c.poses), (sorted(e.poses), sorted(c.poses))
            gaps.append(max((float(np.linalg.norm(np.asarray(p.p) - np.asarray(c.poses[a].p)))
                             for a, p in e.poses.items()), default=0.0))
    return gaps


@pytest.mark.slow
def test_a_flood_of_small_forged_frames_at_a_member_leaves_the_estimate_exact(tmp_path):
    """~3,000 small bad-signature frames a second at A2 (not the reference): on every step the reference reports
    converged it equals the centralized estimate (1 mm), most steps converge, every agent stays under 1 GB."""
    sim, central, est, flood = _launch_flooded(tmp_path, "small", 3000.0)
    assert flood["sent"] > 20_000 and flood["peak_rss"] < GIB
    gaps = _gaps_on_converged(central, est)
    assert len(gaps) >= len(sim.log.steps) // 2 and max(gaps) < 1e-3, gaps
    assert est.stats["rejected"]["bad_signature"] + est.stats["rejected"].get("rate", 0) > 0


@pytest.mark.slow
def test_a_flood_of_16_mib_frames_on_one_connection_leaves_the_estimate_exact_and_memory_bounded(tmp_path):
    """16 MiB bad frames on one connection at A2: refused by size before they are read; every agent under 1 GB
    and the reference equal to the centralized estimate on its converged steps."""
    sim, central, est, flood = _launch_flooded(tmp_path, "big", 0.0)
    assert flood["sent"] > 0 and flood["peak_rss"] < GIB, flood
    gaps = _gaps_on_converged(central, est)
    assert len(gaps) >= len(sim.log.steps) // 2 and max(gaps) < 1e-3, gaps


def _replay_old_mission(work: str, key_bytes: bytes, out: str) -> None:
    """Send every agent genuine A3 frames signed with A3's key but sent 60 s ago (an earlier mission)."""
    import zmq

    from protocols.auth import private_key_from_bytes, seal
    from protocols.messages import BROADCAST, Heartbeat
    from protocols.peers import load_peers

    workdir = Path(work)
    _wait_for_agents(workdir, 4)
    peers = load_peers(workdir / "peers.json")
    key = private_key_from_bytes(key_bytes)
    then = time.time() - 60.0
    epoch = int((then - 5.0) * 1e9)
    frames = [seal(key, "A3", epoch, i, then + 0.05 * i, Heartbeat(sender="A3", receiver=BROADCAST, round=i,
                                                                   t=0.0).to_bytes()) for i in range(50)]
    ctx = zmq.Context()
    sent = 0
    for name, peer in peers.items():
        if name == "A3":
            continue
        push = ctx.socket(zmq.PUSH)
        push.connect(peer.address)
        for f in frames:
            push.send(f)
            sent += 1
        push.close(linger=2000)
    ctx.term()
    Path(out).write_text(json.dumps({"sent": sent}))


@pytest.mark.slow
def test_frames_of_an_earlier_mission_are_refused_and_the_absent_member_stays_missing(tmp_path, monkeypatch):
    """A3 is absent; genuine A3 frames recorded in an earlier mission with the same keys are replayed at every
    agent: all refused as stale, A3 stays in `missing`, and the others equal the centralized estimate without A3."""
    import protocols.auth as auth

    keys = [auth.new_private_key() for _ in range(5)]
    made = iter(keys)
    monkeypatch.setattr(auth, "new_private_key", lambda: next(made))  # the same keys as the earlier mission
    sim = simulate(get_scenario("multi", n_assemblies=5, steps=10), seed=1)
    work, report = tmp_path / "work", tmp_path / "replay.json"
    replayer = multiprocessing.get_context("spawn").Process(
        target=_replay_old_mission, args=(str(work), auth.private_key_bytes(keys[3]), str(report)))
    replayer.start()
    try:
        est = launch(sim.log, LaunchConfig(absent=("A3",), rate=0.4, round_period=0.025, transport="zmq"),
                     workdir=work).estimate  # (the replayer pushes its frames over ZeroMQ)
    finally:
        replayer.join(timeout=120)
        if replayer.is_alive():
            replayer.kill()
    sent = json.loads(report.read_text())["sent"]
    assert sent == 200 and est.stats["rejected"].get("stale") == sent, est.stats["rejected"]
    assert est.stats["missing"] == ["A3"]
    central = estimate_log(without(sim.log, "A3"), EstimatorConfig(window=5))
    cut = lambda e: type(e)(e.reference, e.steps[3:], e.stats)  # noqa: E731
    from decentral.metrics import estimate_gap

    dp, dth, mismatched = estimate_gap(cut(central), cut(est))
    assert mismatched == 0 and dp < 1e-3, (dp, mismatched)


def _claiming(parts: dict, liar: str, victim: str) -> dict:
    """The parts with ``liar``'s configuration also listing every node id of ``victim`` (at made-up centres)."""
    import dataclasses

    part = parts[liar]
    victim_ids = {int(i) for s in parts[victim].steps for i in s.config.get(victim, {})}
    steps = []
    for s in part.steps:
        config = dict(s.config)
        config[liar] = {**config[liar], **{i: np.array([0.5, 0.1 * j, 0.0]) for j, i in enumerate(sorted(victim_ids))}}
        steps.append(dataclasses.replace(s, config=config))
    return {**parts, liar: dataclasses.replace(part, steps=tuple(steps))}


def _launch_with_a_claimed_id_lie(tmp_path, monkeypatch):
    import sims.runners.launch as launch_module

    sim = simulate(get_scenario("multi", n_assemblies=5, steps=10), seed=1)
    real_split = launch_module.split_log
    monkeypatch.setattr(launch_module, "split_log", lambda log: _claiming(real_split(log), "A3", "A1"))
    est = launch(sim.log, LaunchConfig(**PACE), workdir=tmp_path).estimate
    return sim, est


@pytest.mark.slow
def test_a_member_claiming_anothers_node_ids_is_named_and_never_placed(tmp_path, monkeypatch):
    """A3's part lists A1's node ids as its own: the reference names A3 in `excluded` and never places it."""
    sim, est = _launch_with_a_claimed_id_lie(tmp_path, monkeypatch)
    assert est.stats["excluded"] == ["A3"]
    assert not any("A3" in step.poses for step in est.steps)


@pytest.mark.slow
def test_a_member_claiming_anothers_node_ids_leaves_every_converged_step_exact(tmp_path, monkeypatch):
    """With the same lie, every step the reference reports converged equals the centralized estimate without A3."""
    sim, est = _launch_with_a_claimed_id_lie(tmp_path, monkeypatch)
    central = estimate_log(without(sim.log, "A3"), EstimatorConfig(window=5))
    gaps = _gaps_on_converged(central, est)
    assert gaps and max(gaps) < 1e-3, gaps


@pytest.mark.slow
def test_a_claimed_node_id_lie_leaves_the_centralized_estimate_without_the_liar_in_the_simulated_runtime():
    """The same lie on the simulated network: every step equals the centralized estimate without A3 (1 mm)."""
    from decentral.metrics import estimate_gap
    from sims.runners.admm_run import run_admm
    from sims.runners.parts import split_log

    sim = simulate(get_scenario("multi", n_assemblies=5, steps=8), seed=1)
    lying = _claiming(split_log(sim.log), "A3", "A1")
    steps = tuple(type(s)(**{**s.__dict__, "config": {**s.config, "A3": lying["A3"].steps[k].config["A3"]}})
                  for k, s in enumerate(sim.log.steps))
    import dataclasses

    run = run_admm(dataclasses.replace(sim.log, steps=steps), "A0")
    central = estimate_log(without(sim.log, "A3"), EstimatorConfig(window=5))
    dp, dth, mismatched = estimate_gap(central, run.estimate)
    assert mismatched == 0 and dp < 1e-3, (dp, mismatched)
