"""``decentral launch`` / ``decentral agent``: real processes on loopback, the real transport, local decisions.

The machine these run on is shared and loaded, so the tests run the log slower than its timestamps
(``rate`` < 1) to give every window its 20-40 rounds; the protocol is the same at any pace.
"""

import json
import multiprocessing
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from decentral.estimator import EstimatorConfig, estimate_log
from decentral.metrics import estimate_gap, score_estimate
from sims.cli.main import main
from sims.io.log_json import write_log
from sims.runners.launch import CrashPlan, LaunchConfig, launch, parse_crash
from sims.simulation.scenarios import get_scenario, simulate
from tests.synthetic import without

POS_TOL, YAW_TOL = 1e-3, np.radians(0.05)
#: 20 rounds of 25 ms per 0.2 s log step
PACE = dict(rate=0.4, round_period=0.025)
REASONS = {"bad_signature", "replay", "unknown_sender", "malformed"}


def _sim(n, steps, seed=1):
    return simulate(get_scenario("multi", n_assemblies=n, steps=steps), seed=seed)


def _gap_from(central, estimate, first=0):
    """(position, yaw, mismatched) of the estimate against the centralized one from step ``first`` on."""
    cut = lambda e: type(e)(e.reference, e.steps[first:], e.stats)  # noqa: E731
    return estimate_gap(cut(central), cut(estimate))


def _children_of(pid):
    out = subprocess.run(["ps", "-o", "pid=", "--ppid", str(pid)], capture_output=True, text=True).stdout
    return [int(p) for p in out.split()]


def test_launch_on_a_four_ring_gives_the_centralized_estimate_with_the_contract_stats(tmp_path):
    """4 processes, no loss: every step equals the centralized estimate (1 mm, 0.05 deg), same assemblies placed."""
    sim = _sim(4, 8)
    central = estimate_log(sim.log, EstimatorConfig(window=5))
    result = launch(sim.log, LaunchConfig(**PACE), workdir=tmp_path)
    est = result.estimate
    assert len(est.steps) == len(sim.log.steps)
    dp, dth, mismatched = estimate_gap(central, est)
    assert mismatched == 0 and dp < POS_TOL and dth < YAW_TOL, (dp, np.degrees(dth))
    stats = est.stats
    assert stats["processes"] == 4 and stats["restarts"] == {n: 0 for n in sim.log.assemblies}
    for key in ("messages", "bytes"):
        per = stats[key]["per_agent"]
        assert set(per) == set(sim.log.assemblies) and all(v > 0 for v in per.values())
        assert stats[key]["total"] == sum(per.values())
    assert stats["bytes"]["total"] > 100 * stats["messages"]["total"]  # framing (98+ B per frame) included
    assert set(stats["rejected"]) >= REASONS and sum(stats["rejected"].values()) == 0
    assert stats["missing"] == [] and stats["status"] == "ok"
    keys = list(Path(tmp_path).glob("*.key"))
    assert len(keys) == 4 and all(k.stat().st_mode & 0o777 == 0o600 for k in keys)
    assert not any(os.path.exists(f"/proc/{pid}") and _alive(pid) for pid in _pids(tmp_path))


def test_a_workdir_used_before_does_not_lend_its_records_to_the_next_launch(tmp_path):
    """The agents append to their streams: a --workdir holding an earlier run's records (here a made-up one that
    excluded A2 and placed A1 10 m away) must not mix into the next run's estimate or stats."""
    sim = _sim(4, 4)
    stale = {"step": 0, "t": 0.0, "poses": {"A1": {"p": [10.0, 0.0, 0.0], "theta": 0.0}}, "unplaced": {},
             "converged": True, "without": [], "rounds": 1, "counts": {"messages": 1, "bytes": 1, "rejected": {}},
             "excluded": ["A2"], "suspects": [], "behind_ms": [900.0, 900.0, 900.0], "cpu_ms": 900.0}
    (tmp_path / "A0.0.jsonl").write_text(json.dumps(stale) + "\n")
    result = launch(sim.log, LaunchConfig(**PACE), workdir=tmp_path)
    stats = result.estimate.stats
    assert stats["excluded"] == [] and stats["behind_ms"]["A0"][1] < 900.0
    dp, _, mismatched = estimate_gap(estimate_log(sim.log, EstimatorConfig(window=5)), result.estimate)
    assert mismatched == 0 and dp < POS_TOL


def test_launch_shares_by_broadcast_when_asked_and_still_gives_the_centralized_estimate(tmp_path):
    """`--aggregation broadcast`: no window goes through the tree, and every step equals the centralized estimate."""
    sim = _sim(4, 4)
    result = launch(sim.log, LaunchConfig(**PACE, aggregation="broadcast"), workdir=tmp_path)
    assert result.estimate.stats["aggregation"] == "broadcast"
    counters = [rec["counters"] for run in result.records["A0"] for rec in run if "step" in rec]
    assert counters and counters[-1]["tree_windows"] == 0 and counters[-1]["broadcast_windows"] >= 4
    dp, _, mismatched = estimate_gap(estimate_log(sim.log, EstimatorConfig(window=5)), result.estimate)
    assert mismatched == 0 and dp < POS_TOL


def _pids(workdir):
    return [int(p.read_text()) for p in Path(workdir).glob("*.pid")]


def _alive(pid):
    try:
        state = Path(f"/proc/{pid}/stat").read_text().split()[2]
    except OSError:
        return False
    return state != "Z"


def test_launch_leaves_no_process_behind_when_it_is_terminated(tmp_path):
    """SIGTERM to `decentral launch` while its agents run: exit 143 with one stderr line, no agent survives."""
    sim = _sim(3, 40)
    log_path = tmp_path / "log.json"
    write_log(log_path, sim.log)
    work = tmp_path / "work"
    proc = subprocess.Popen([sys.executable, "-m", "sims.cli.main", "launch", str(log_path), "-o",
                             str(tmp_path / "est.json"), "--workdir", str(work)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 90
    while time.monotonic() < deadline and not list(work.glob("*.0.jsonl")):
        time.sleep(0.2)
    assert list(work.glob("*.0.jsonl")), "agents never started"
    children = _children_of(proc.pid)
    assert len(children) == 3
    proc.send_signal(signal.SIGTERM)
    proc.wait(timeout=30)
    err = proc.stderr.read().decode()
    assert proc.returncode == 143 and err.strip() == "decentral launch: terminated", (proc.returncode, err)
    time.sleep(0.5)
    assert not [pid for pid in children if _alive(pid)]
    assert not (tmp_path / "est.json").exists()


def test_agent_refuses_a_key_of_another_agent_in_one_line(tmp_path, capsys):
    """Bad input to `decentral agent` ends with one line naming the file, exit status 2."""
    sim = _sim(2, 2)
    main(["keys", "A0", "A1", "-o", str(tmp_path / "keys")])
    capsys.readouterr()
    from sims.runners.parts import split_log, write_part

    write_part(tmp_path / "A0.json", split_log(sim.log)["A0"], "A0")
    key_a1 = next((tmp_path / "keys").glob("A1.key*"))
    status = main(["agent", "A0", "--log", str(tmp_path / "A0.json"), "--peers", str(tmp_path / "keys" / "peers.json"),
                   "--key", str(key_a1)])
    err = capsys.readouterr().err
    assert status == 2 and len(err.strip().splitlines()) == 1 and str(key_a1) in err


def test_crash_plans_parse_and_bad_ones_are_refused():
    """NAME@STEP[+DOWN] parses; anything else is an InputError naming --crash."""
    assert parse_crash("A2@40+10") == CrashPlan("A2", 40, 10)
    assert parse_crash("A2@40") == CrashPlan("A2", 40, None)
    with pytest.raises(Exception, match="--crash"):
        parse_crash("A2-40")


@pytest.mark.slow
@pytest.mark.parametrize("n", [6, 8])
def test_launch_on_larger_rings_gives_the_centralized_estimate(n, tmp_path):
    """6 and 8 processes, no loss: equal to the centralized estimate at every step, same assemblies placed."""
    sim = _sim(n, 8)
    central = estimate_log(sim.log, EstimatorConfig(window=5))
    est = launch(sim.log, LaunchConfig(**PACE), workdir=tmp_path).estimate
    dp, dth, mismatched = estimate_gap(central, est)
    assert mismatched == 0 and dp < POS_TOL and dth < YAW_TOL, (dp, np.degrees(dth))


@pytest.mark.slow
def test_the_last_step_goes_on_in_the_background_after_the_log_ends(tmp_path):
    """A 4-ring of two steps at 4 rounds of 25 ms a step: the last window, like the cold start before it, needs more
    than its own step period; it goes on in the background after the log ends and its converged answer replaces
    the first record (without it the last step stayed unconverged at this pace). Every step is then converged and
    the centralized estimate (1 mm, 0.05 deg)."""
    sim = _sim(4, 2)
    central = estimate_log(sim.log, EstimatorConfig(window=5))
    est = launch(sim.log, LaunchConfig(rate=2.0, round_period=0.025), workdir=tmp_path).estimate
    assert list(est.stats["converged_per_step"]) == [True, True] and est.stats["status"] == "ok"
    dp, dth, mismatched = estimate_gap(central, est)
    assert mismatched == 0 and dp < POS_TOL and dth < YAW_TOL, (dp, np.degrees(dth))


@pytest.mark.slow
@pytest.mark.parametrize("loss", [0.1, 0.3])
def test_launch_under_receive_side_loss_stays_within_the_admm_tolerance(loss, tmp_path):
    """10 % and 30 % of frames dropped at the receivers: error vs truth within 2x the centralized one,
    the same assemblies placed at the last step (the simulated runner's loss tolerance)."""
    sim = _sim(4, 10)
    central = estimate_log(sim.log, EstimatorConfig(window=5))
    est = launch(sim.log, LaunchConfig(loss=loss, seed=3, rate=0.2, round_period=0.025), workdir=tmp_path).estimate
    assert est.steps[-1].poses.keys() == central.steps[-1].poses.keys()
    err = score_estimate(sim.truth.poses, est).overall.position_m
    assert err <= 2 * score_estimate(sim.truth.poses, central).overall.position_m
    assert est.stats["loss"] == loss


@pytest.mark.slow
def test_a_killed_agent_restarts_fresh_and_catches_up_within_ten_steps(tmp_path):
    """A2 is SIGKILLed at step 6 and restarted 3 steps later: the estimate covers every step, places
    assemblies at every step (also while A2 is down), and from 10 steps after the restart on equals the
    centralized estimate again."""
    sim = _sim(5, 24)
    central = estimate_log(sim.log, EstimatorConfig(window=5))
    est = launch(sim.log, LaunchConfig(crashes=(CrashPlan("A2", 6, 3),), **PACE), workdir=tmp_path).estimate
    assert len(est.steps) == 24 and [s.t for s in est.steps] == [s.t for s in sim.log.steps]
    assert est.stats["restarts"]["A2"] == 1 and est.stats["processes"] == 6
    assert all(step.poses for step in est.steps), [sorted(step.unplaced.values()) for step in est.steps]
    dp, dth, mismatched = _gap_from(central, est, first=9 + 10)
    assert mismatched == 0 and dp < POS_TOL and dth < YAW_TOL, (dp, np.degrees(dth))


@pytest.mark.slow
def test_a_peer_that_never_starts_hangs_nobody(tmp_path):
    """A3 never starts: launch ends on its own, the reference says it never heard from A3, the two windows that
    wait for it are the only ones that do not converge (status degraded), and from then on it places what the
    centralized estimator places without A3's data."""
    sim = _sim(5, 10)
    began = time.monotonic()
    est = launch(sim.log, LaunchConfig(absent=("A3",), **PACE), workdir=tmp_path).estimate
    assert time.monotonic() - began < 60 and est.stats["status"] == "degraded"
    assert all(est.stats["converged_per_step"][2:]), est.stats["converged_per_step"]
    assert est.stats["missing"] == ["A3"] and est.stats["processes"] == 4
    central = estimate_log(without(sim.log, "A3"), EstimatorConfig(window=5))
    dp, dth, mismatched = _gap_from(central, est, first=3)
    assert mismatched == 0 and dp < POS_TOL and dth < YAW_TOL, (dp, np.degrees(dth))


def _attack(workdir: str, n_frames: int, seed: int, out: str, chunk: int = 1000, pause: float = 0.15) -> None:
    """Flood every agent of a running launch: wait for its first steps, then send hostile frames, ``chunk``
    to each agent in turn with a ``pause`` between rounds (a flood as fast as the socket takes it starves
    the 2-core machine's CPU, which is a denial of service, not the acceptance of a frame)."""
    from protocols.auth import private_key_bytes, seal
    from protocols.messages import BROADCAST, Heartbeat
    from protocols.peers import load_peers, load_private_key
    from protocols.testing.attacker import flood

    work = Path(workdir)
    deadline = time.monotonic() + 120
    # once every agent has finished a step it has heard every member (a receiver that never heard a sender
    # would take a captured frame of that sender's old process once: it has nothing to tell it is old)
    while time.monotonic() < deadline and not (len(list(work.glob("*.0.jsonl"))) == 4 and all(
            p.stat().st_size for p in work.glob("*.0.jsonl"))):
        time.sleep(0.1)
    peers = load_peers(work / "peers.json")
    name, key = load_private_key(next(work.glob("A1.key*")))
    # genuine A1 frames of an old process epoch: valid signatures, refused as replays (flipped: bad signature)
    captured = [seal(key, "A1", 1, i, 0.0, Heartbeat(sender="A1", receiver=BROADCAST, round=i, t=0.0).to_bytes())
                for i in range(20)]
    rng = np.random.default_rng(seed)
    expected, sent = {}, 0
    left = {name: n_frames // len(peers) for name in peers}
    while any(left.values()):
        for name, peer in peers.items():
            if not left[name]:
                continue
            report = flood(peer.address, min(chunk, left[name]), rng, senders=list(peers), captured=captured,
                           insider=("A1", private_key_bytes(key)))
            left[name] -= report.sent
            sent += report.sent
            for reason, n in report.expected.items():
                expected[reason] = expected.get(reason, 0) + n
        time.sleep(pause)
    Path(out).write_text(json.dumps({"sent": sent, "expected": expected}))


def _launch_under_attack(tmp_path, n_frames, steps, pace=PACE):
    sim = _sim(4, steps)
    central = estimate_log(sim.log, EstimatorConfig(window=5))
    work = tmp_path / "work"
    report = tmp_path / "attack.json"
    attacker = multiprocessing.get_context("spawn").Process(target=_attack, args=(str(work), n_frames, 7, str(report)))
    attacker.start()
    try:
        est = launch(sim.log, LaunchConfig(**pace, transport="zmq"), workdir=work).estimate  # the attacker speaks ZeroMQ
    finally:
        attacker.join(timeout=120)
        if attacker.is_alive():
            attacker.kill()
    attack = json.loads(report.read_text())
    assert attack["sent"] == n_frames // 4 * 4
    assert est.stats["status"] == "ok" and "agent_errors" not in est.stats  # zero crashes
    from protocols.testing.attacker import as_expected

    rejected = {k: v for k, v in est.stats["rejected"].items() if v}
    assert as_expected(rejected) == attack["expected"] and sum(rejected.values()) == attack["sent"]
    dp, dth, mismatched = estimate_gap(central, est)
    assert mismatched == 0 and dp < POS_TOL and dth < YAW_TOL, (dp, np.degrees(dth))


def test_a_live_attack_is_refused_frame_by_frame_and_changes_nothing(tmp_path):
    """While 4 agents run, another process sends 2,000 hostile frames (random, truncated, forged, replayed,
    impersonating, unknown sender): no crash, every frame counted in `rejected` by its reason, the
    estimate still the centralized one."""
    _launch_under_attack(tmp_path, 2_000, 12)


@pytest.mark.slow
def test_a_live_attack_of_a_hundred_thousand_frames_is_refused_and_changes_nothing(tmp_path):
    """The same with 100,000 frames (about 5,000 a second over ~25 s of a 60-step run at 50 ms rounds: the
    signature checks take CPU the agents' rounds need on the loaded 2-core machine)."""
    _launch_under_attack(tmp_path, 100_000, 60, pace=dict(rate=0.2, round_period=0.05))


@pytest.mark.parametrize("timeout, says", [(None, "30 s after the last step"), ("5", "timed out after 5 s")])
def test_a_run_cut_short_says_why_and_exits_1(tmp_path, monkeypatch, capsys, timeout, says):
    """A launch whose agents were cut short (its --timeout, or still running 30 s after the last step) names the cause
    and the status on stderr, writes what was gathered and exits 1 (not 'after None s')."""
    import sims.runners.launch as runner
    from decentral.observations import Estimate, EstimateStep
    from sims.runners.launch import LaunchResult

    sim = _sim(2, 2)
    write_log(tmp_path / "log.json", sim.log)
    steps = tuple(EstimateStep(s.t, {}, {"A1": "no_consensus"}) for s in sim.log.steps)
    stats = {"status": "timeout", "missing": [], "processes": 2, "messages": {"total": 0}, "bytes": {"total": 0},
             "rejected": {}}
    monkeypatch.setattr(runner, "launch", lambda log, config, workdir=None: LaunchResult(
        Estimate("A0", steps, stats), {}, timed_out=True))
    args = ["launch", str(tmp_path / "log.json"), "-o", str(tmp_path / "est.json")]
    assert main(args + (["--timeout", timeout] if timeout else [])) == 1
    err = capsys.readouterr().err
    assert says in err and "status timeout" in err and "None" not in err, err
    assert (tmp_path / "est.json").exists()
