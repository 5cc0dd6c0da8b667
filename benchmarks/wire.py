"""Wire encoding and simulated-network throughput of the protocols layer.

Fixed inputs: one message of each kind with typical payloads (a 6-detection ``Tracks``, 5-robot
``PoseEstimates``, ``AdmmPrimal``/``AdmmDual`` with four 2 x 2 and four 3-vector blocks, a 4-step
``OdometryReport``, a ``Heartbeat``). Per kind: exact size in bytes, median encode and decode time
over 2000 repetitions (after 200 warm-up calls). Network: 8 agents broadcasting one ``AdmmPrimal``
per round for 200 rounds over a lossy link (30 % loss, 5 % duplication, jitter), median seconds per
delivered message; ratio of a broadcast's cost to a raw ``to_bytes`` + ``decode`` of the same frame
measured in the same run. Single core.

Usage: ``python benchmarks/wire.py``; writes ``OUT/wire.json``.
"""

from __future__ import annotations

import time

from _common import machine, parser, save  # noqa: I001  (pins threads before numpy)

import numpy as np

from protocols.messages import (
    BROADCAST,
    AdmmDual,
    AdmmPrimal,
    Heartbeat,
    OdometryReport,
    PoseEstimates,
    Tracks,
    decode,
)
from protocols.network import LinkConfig, NetworkConfig, SimulatedNetwork

REPS, WARM = 2000, 200


def samples() -> dict:
    rng = np.random.default_rng(0)
    blocks = {**{f"R{i}": rng.normal(size=(2, 2)) for i in range(4)}, **{f"p{i}": rng.normal(size=3) for i in range(4)}}
    return {
        "tracks": Tracks(sender="A0", receiver=BROADCAST, round=7, t=1.4, camera="A0/cam0",
                         ids=np.arange(6), uvr=rng.uniform(0, 600, (6, 3))),
        "pose_estimates": PoseEstimates(sender="R0", receiver=BROADCAST, round=7, t=1.4,
                                        subjects=tuple(f"R{i}" for i in range(1, 6)),
                                        poses=rng.normal(size=(5, 3)), covariances=np.tile(np.eye(3), (5, 1, 1))),
        "admm.primal": AdmmPrimal(sender="A0", receiver="A1", round=7, window=3, blocks=blocks),
        "admm.dual": AdmmDual(sender="A0", receiver="A1", round=7, window=3, blocks=blocks, rho=2.0),
        "odometry": OdometryReport(sender="R0", receiver=BROADCAST, round=7, t=1.4, motions=rng.normal(size=(4, 3)),
                                   covariances=np.tile(np.eye(3) * 1e-4, (4, 1, 1))),
        "heartbeat": Heartbeat(sender="A0", receiver="A1", round=7, t=1.4),
    }


def median_time(fn, reps: int = REPS) -> float:
    for _ in range(WARM):
        fn()
    out = np.empty(reps)
    for i in range(reps):
        t0 = time.perf_counter()
        fn()
        out[i] = time.perf_counter() - t0
    return float(np.median(out))


def network_rate(msg: AdmmPrimal, n_agents: int = 8, rounds: int = 200) -> dict:
    names = tuple(f"A{i}" for i in range(n_agents))
    net = SimulatedNetwork(NetworkConfig(agents=names, link=LinkConfig(drop=0.3, duplicate=0.05, latency=0.001,
                                                                      jitter=0.002), round_period=0.01),
                           np.random.default_rng(0))
    per_round = []
    delivered = 0
    for k in range(rounds):
        t = k * 0.01
        t0 = time.perf_counter()
        for a in names:
            net.send(AdmmPrimal(sender=a, receiver=BROADCAST, round=k, window=0, blocks=msg.blocks), t)
        for a in names:
            delivered += len(net.poll(a, t + 0.009))
        per_round.append(time.perf_counter() - t0)
    s = net.stats()
    return {
        "agents": n_agents,
        "rounds": rounds,
        "median_round_s": float(np.median(per_round)),
        "delivered": delivered,
        "sent": s.total.sent,
        "dropped": s.total.dropped,
        "duplicated": s.total.duplicated,
        "seconds_per_delivered_message": float(np.sum(per_round) / max(delivered, 1)),
        "balanced": s.total.balanced(),
    }


def main(argv=None) -> None:
    args = parser(__doc__).parse_args(argv)
    info = machine()
    kinds = {}
    for kind, msg in samples().items():
        frame = msg.to_bytes()
        kinds[kind] = {
            "size_bytes": msg.size_bytes,
            "encode_median_us": 1e6 * median_time(msg.to_bytes),
            "decode_median_us": 1e6 * median_time(lambda f=frame: decode(f)),
        }
    primal = samples()["admm.primal"]
    net = network_rate(primal)
    raw = kinds["admm.primal"]["encode_median_us"] + kinds["admm.primal"]["decode_median_us"]
    net["ratio_per_delivered_vs_encode_plus_decode"] = 1e6 * net["seconds_per_delivered_message"] / raw
    save("wire", {"benchmark": "wire", "parameters": {"repetitions": REPS, "warmup": WARM}, "machine": info,
                  "kinds": kinds, "network": net}, args.out)


if __name__ == "__main__":
    main()
