"""What hostile frames cost a receiving agent, and the flood an agent absorbs while its estimate stays exact.

Two measurements, both on loopback:

* **cost per refused frame, by kind**: one receiving :class:`protocols.zmq_transport.ZmqTransport`
  in this process, an attacker socket sending ``--frames`` frames of one kind; the receiver's CPU
  time (``time.process_time``) from the first frame until every frame is counted in its
  ``rejected``, divided by the frames. Kinds: random bytes, an unknown sender, a replayed genuine
  frame, a forged small frame (a member's name, a wrong signature), a forged 1 MiB frame, a 5 MiB
  frame over the size limit (10 of them: each drops its connection, counted ``oversize``, and the
  attacker's socket, in this process, reconnects and sends the next; its CPU is included). The
  reasons the receiver gave are recorded (under a flood, frames past the rate budget are refused
  as ``rate`` before their signature is checked). A genuine small frame's cost is the reference.
* **flood absorbed**: ``decentral launch`` of a 5-assembly log (``--rate 0.2 --round-period 0.05``)
  while another process sends forged small frames (a member's name, a wrong signature) at a
  non-reference member (A2) at each rate of ``--rates`` frames per second; per rate, the largest
  distance between the reference's estimate and the centralized estimate on the steps it reports
  converged, how many steps converged, the frames the agents refused, and the largest resident
  memory of an agent. The largest rate with every converged step within 1 mm and at least as many
  converged steps as without a flood minus one is the rate "absorbed".
* **CurveZMQ**: CPU per frame over loopback with and without ZeroMQ's CURVE encryption (keys
  derived from Ed25519 keys), small and 64 KiB frames: the cost of refusing outsiders at the
  connection instead.

The machine is shared: every timing is printed beside the load average, and the per-frame costs
are also given as ratios to the genuine frame measured in the same run. Run it once on the code to
compare with (``PYTHONPATH=OLD_TREE python benchmarks/flood.py``) and once on this code.

Usage: ``python benchmarks/flood.py [--out DIR] [--name NAME] [--frames 2000] [--rates 0 1000 3000 6000]
[--steps 10]``; writes ``DIR/NAME.json`` (default ``out/benchmarks/flood.json``).
"""

from __future__ import annotations

import json
import multiprocessing
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
if not os.environ.get("PYTHONPATH"):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def build_parser():
    from _common import parser as common_parser

    parser = common_parser(__doc__)
    parser.add_argument("--name", default="flood", help="result file name (default: flood)")
    parser.add_argument("--frames", type=int, default=2000, help="frames per kind (cost per frame)")
    parser.add_argument("--rates", type=float, nargs="*", default=[0, 1000, 3000, 6000],
                        help="flood rates, frames per second at A2")
    parser.add_argument("--steps", type=int, default=10, help="log steps of each launch")
    parser.add_argument("--force", action="store_true", help="replace an existing result file")
    return parser


# ---------------------------------------------------------------------------- cost per frame
def _frames(kind: str, n: int, rng, captured: bytes, member: str) -> list[bytes]:
    from protocols.auth import private_key_from_bytes, seal
    from protocols.messages import BROADCAST, Heartbeat

    if kind == "random":
        return [b"\x00" + rng.bytes(200) for _ in range(n)]
    if kind == "replay":
        return [captured] * n
    if kind == "oversize_5MiB":  # over the 4 MiB limit: libzmq drops the connection (counted ``oversize``)
        return [b"\x00" * (5 * 2**20)] * n
    size = 2**20 if kind == "forged_1MiB" else 0
    sender = member if kind.startswith("forged") else "intruder"
    key = private_key_from_bytes(rng.bytes(32))
    pad = b"\x00" * size
    out = []
    for i in range(n):
        inner = Heartbeat(sender=sender, receiver=BROADCAST, round=i, t=0.0).to_bytes()
        out.append(seal(key, sender, 2**62 + i, i, time.time(), inner + pad)[: None])
    return out


def cost_per_frame(n_frames: int, seed: int = 0) -> dict:
    """CPU seconds per frame the receiver spends on each kind of hostile frame (and on a genuine one)."""
    import numpy as np
    import zmq

    from protocols.messages import BROADCAST, Heartbeat
    from protocols.zmq_transport import open_loopback

    rng = np.random.default_rng(seed)
    out = {}
    kinds = ["genuine", "random", "unknown_sender", "replay", "forged_small", "forged_1MiB", "oversize_5MiB"]
    for kind in kinds:
        nets, table = open_loopback(["A0", "A1"])
        ctx = zmq.Context()
        push = ctx.socket(zmq.PUSH)
        push.setsockopt(zmq.SNDHWM, 0)
        push.connect(table["A1"].address)
        try:
            a0, a1 = nets["A0"], nets["A1"]
            # one genuine frame admitted first, so that a replay of it is stale (the receiver has heard A0)
            a0.send(Heartbeat(sender="A0", receiver="A1", round=0, t=0.0), time.time())
            deadline = time.monotonic() + 10
            got = []
            while not got and time.monotonic() < deadline:
                a1.wait(0.05)
                got = a1.poll("A1", time.time())
            n = {"forged_1MiB": max(20, n_frames // 50), "oversize_5MiB": 10}.get(kind, n_frames)
            if kind == "genuine":
                for i in range(n):
                    a0.send(Heartbeat(sender="A0", receiver="A1", round=i + 1, t=0.0), time.time())
            else:
                frames = _frames(kind, n, rng, _captured(a0), "A0")
                for f in frames:
                    push.send(f)
            t_cpu, t_wall, seen, delivered, reasons = time.process_time(), time.perf_counter(), 0, 0, {}
            last, stalled = 0, time.monotonic()
            while seen < n and time.monotonic() - stalled < 3.0:
                a1.wait(0.01)
                delivered += len(a1.poll("A1", time.time()))
                reasons = {k: v for k, v in a1.stats().rejected.items() if v}
                seen = delivered if kind == "genuine" else sum(reasons.values())
                if seen > last:
                    last, stalled = seen, time.monotonic()
            cpu, wall = time.process_time() - t_cpu, time.perf_counter() - t_wall
            out[kind] = {"frames": n, "counted": int(seen), "cpu_us_per_frame": 1e6 * cpu / max(seen, 1),
                         "wall_us_per_frame": 1e6 * wall / max(seen, 1), "reasons": reasons,
                         "loadavg": list(os.getloadavg())}
        finally:
            push.close(linger=0)
            ctx.term()
            for t in nets.values():
                t.close()
    ref = out["genuine"]["cpu_us_per_frame"]
    for kind in kinds:
        out[kind]["ratio_to_genuine"] = out[kind]["cpu_us_per_frame"] / ref
    return out


def _captured(sender_transport) -> bytes:
    """A genuine envelope of A0 with sequence number 0 (already admitted by A1: a replay)."""
    from protocols.auth import seal
    from protocols.messages import Heartbeat

    signer = sender_transport._local["A0"].signer
    return seal(signer._key, "A0", signer.epoch, 0, time.time(), Heartbeat(sender="A0", receiver="A1", round=0,
                                                                           t=0.0).to_bytes())


# ---------------------------------------------------------------------------- CurveZMQ
def curve_cost(sizes=(300, 65536), reps: int = 3) -> dict:
    """CPU (both ends, libzmq's I/O threads included) per frame over loopback, plain TCP against CurveZMQ with
    keys derived from Ed25519 ones (as agents would derive them from their signing keys); medians of ``reps``."""
    import numpy as np
    import zmq
    import zmq.utils.z85
    from nacl.bindings import crypto_sign_ed25519_pk_to_curve25519, crypto_sign_ed25519_sk_to_curve25519
    from nacl.signing import SigningKey

    def curve_keys(sk):
        public = crypto_sign_ed25519_pk_to_curve25519(bytes(sk.verify_key))
        secret = crypto_sign_ed25519_sk_to_curve25519(bytes(sk) + bytes(sk.verify_key))
        return zmq.utils.z85.encode(public), zmq.utils.z85.encode(secret)

    def once(curve: bool, n: int, size: int) -> float:
        ctx = zmq.Context()
        pull, push = ctx.socket(zmq.PULL), ctx.socket(zmq.PUSH)
        if curve:
            (spk, ssk), (cpk, csk) = curve_keys(SigningKey.generate()), curve_keys(SigningKey.generate())
            pull.curve_server, pull.curve_secretkey, pull.curve_publickey = True, ssk, spk
            push.curve_serverkey, push.curve_publickey, push.curve_secretkey = spk, cpk, csk
        pull.bind("tcp://127.0.0.1:*")
        push.setsockopt(zmq.SNDHWM, 0)
        push.connect(pull.getsockopt_string(zmq.LAST_ENDPOINT))
        msg = os.urandom(size)
        push.send(msg)
        pull.recv()
        t0 = time.process_time()
        for _ in range(n):
            push.send(msg)
        for _ in range(n):
            pull.recv()
        cpu = time.process_time() - t0
        push.close(0)
        pull.close(0)
        ctx.term()
        return 1e6 * cpu / n

    out = {}
    for size in sizes:
        n = 20000 if size <= 1024 else 2000
        plain = [once(False, n, size) for _ in range(reps)]
        curve = [once(True, n, size) for _ in range(reps)]
        out[f"{size}B"] = {"plain_cpu_us": float(np.median(plain)), "curve_cpu_us": float(np.median(curve)),
                           "ratio": float(np.median(curve) / np.median(plain)), "loadavg": list(os.getloadavg())}
    return out


# ---------------------------------------------------------------------------- flood absorbed
def _flooder(work: str, rate: float, seconds: float, out: str) -> None:
    """Send forged small frames naming A1 at A2 at ``rate`` per second; sample the agents' memory."""
    import numpy as np
    import zmq

    from protocols.peers import load_peers
    from protocols.testing.attacker import record_peak_rss

    workdir = Path(work)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not (len(list(workdir.glob("*.0.jsonl"))) >= 5 and all(
            p.stat().st_size for p in workdir.glob("*.0.jsonl"))):
        time.sleep(0.05)
    peers = load_peers(workdir / "peers.json")
    pids = [int(p.read_text()) for p in workdir.glob("*.pid")]
    rng = np.random.default_rng(1)
    frames = _frames("forged_small", 4096, rng, b"", "A1")
    ctx = zmq.Context()
    push = ctx.socket(zmq.PUSH)
    push.setsockopt(zmq.SNDHWM, 100_000)
    push.connect(peers["A2"].address)
    sent, tried, peak = 0, 0, {}
    t0 = time.monotonic()
    end = t0 + seconds
    next_sample = t0
    while time.monotonic() < end:
        now = time.monotonic()
        due = int((now - t0) * rate)
        while tried < due:
            tried += 1
            try:
                push.send(frames[sent % len(frames)], zmq.NOBLOCK)
                sent += 1
            except zmq.Again:  # the agent's queue is full: TCP pushes back (not sent, not counted)
                pass
        if now >= next_sample:
            next_sample = now + 0.2
            record_peak_rss(pids, peak)
        time.sleep(0.005)
    push.close(linger=0)
    ctx.term()
    Path(out).write_text(json.dumps({"sent": sent, "tried": tried, "seconds": seconds,
                                     "peak_rss_bytes": max(peak.values(), default=0)}))


def flood_absorbed(rates: list[float], steps: int) -> list[dict]:
    """One launch per flood rate: the reference's gap to the centralized estimate on its converged steps."""
    import numpy as np

    from decentral.estimator import EstimatorConfig, estimate_log
    from sims.runners.launch import LaunchConfig, launch
    from sims.simulation.scenarios import get_scenario, simulate

    sim = simulate(get_scenario("multi", n_assemblies=5, steps=steps), seed=1)
    central = estimate_log(sim.log, EstimatorConfig(window=5))
    config = LaunchConfig(rate=0.2, round_period=0.05)
    rows = []
    for rate in rates:
        with tempfile.TemporaryDirectory(prefix="flood-bench-") as tmp:
            work, report = Path(tmp) / "work", Path(tmp) / "flood.json"
            seconds = steps * 1.0 + 2.0
            flooder = multiprocessing.get_context("spawn").Process(target=_flooder,
                                                                     args=(str(work), rate, seconds, str(report)))
            flooder.start()
            load0 = list(os.getloadavg())
            t0 = time.perf_counter()
            try:
                est = launch(sim.log, config, workdir=work).estimate
            finally:
                flooder.join(timeout=180)
                if flooder.is_alive():
                    flooder.kill()
            wall = time.perf_counter() - t0
            flood = json.loads(report.read_text()) if report.exists() else {}
        conv = est.stats["converged_per_step"]
        worst = 0.0
        for k, (c, e) in enumerate(zip(central.steps, est.steps)):
            if not conv[k]:
                continue
            for name, pose in e.poses.items():
                if name in c.poses:
                    worst = max(worst, float(np.linalg.norm(np.asarray(pose.p) - np.asarray(c.poses[name].p))))
                else:
                    worst = float("inf")
        rows.append({"rate": rate, "flood_sent": flood.get("sent"), "flood_tried": flood.get("tried"), "converged_steps": int(sum(conv)),
                     "steps": len(conv), "max_gap_converged_m": worst,
                     "rejected": {k: v for k, v in est.stats["rejected"].items() if v},
                     "agent_peak_rss_mb": flood.get("peak_rss_bytes", 0) / 1e6, "wall_s": wall,
                     "loadavg_start": load0, "loadavg_end": list(os.getloadavg())})
        print(json.dumps(rows[-1]), flush=True)
    base = rows[0]["converged_steps"] if rows and rows[0]["rate"] == 0 else len(rows and rows[0]["steps"] or [])
    for row in rows:
        row["exact"] = bool(row["max_gap_converged_m"] < 1e-3 and row["converged_steps"] >= base - 1)
    return rows


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    from _common import machine, output

    path = output(args.out, args.name)
    if path.exists() and not args.force:
        print(f"{path} exists (use --force to replace it)", file=sys.stderr)
        return 2
    import protocols

    result = {"machine": machine(), "code": str(Path(protocols.__file__).resolve().parents[1]),
              "parameters": {"frames": args.frames, "rates": args.rates, "steps": args.steps,
                             "launch": {"assemblies": 5, "rate": 0.2, "round_period": 0.05, "target": "A2"}}}
    result["cost_per_frame"] = cost_per_frame(args.frames)
    print(json.dumps(result["cost_per_frame"], indent=1), flush=True)
    result["curve"] = curve_cost()
    print(json.dumps(result["curve"], indent=1), flush=True)
    result["flood"] = flood_absorbed(args.rates, args.steps)
    exact = [row["rate"] for row in result["flood"] if row["exact"]]
    result["absorbed_rate"] = max(exact) if exact else None
    result["machine"]["loadavg_end"] = list(os.getloadavg())
    path.write_text(json.dumps(result, indent=1))
    print(f"absorbed rate: {result['absorbed_rate']} frames/s -> {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
