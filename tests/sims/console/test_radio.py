"""The operator swarm's batched radio: the same copies, fates and books as the network's per-message path."""

from __future__ import annotations

import numpy as np

from protocols.messages import BROADCAST, OdometryReport
from protocols.network import LinkConfig
from sims.console.radio import BatchedRadio
from sims.simulation.swarm import SwarmConfig, SwarmSim

CFG = SwarmConfig(n_robots=5, dt=0.1, link=LinkConfig(drop=0.3, latency=0.005, jitter=0.01, duplicate=0.1))


def _messages(names, k):
    rng = np.random.default_rng(k)
    return [OdometryReport(sender=n, receiver=BROADCAST, round=k, t=0.1 * k, motions=rng.normal(size=(2, 3)),
                           covariances=np.tile(np.eye(3) * 1e-4, (2, 1, 1))) for n in names]


def test_batched_radio_delivers_what_the_per_message_path_delivers():
    """Lossy, jittery, duplicating links: each receiver gets the same copies (sender, round, payload) in the
    same order, and the network's books count the same, whichever path carried them."""
    one, many = SwarmSim(CFG, 3), SwarmSim(CFG, 3)
    names = CFG.names
    radio = BatchedRadio(many.network, names)
    sent = np.zeros((len(names), len(names)), np.int64)
    for k in range(6):
        msgs = _messages(names, k)
        for m in msgs:
            one.network.send(m, 0.1 * k)
        radio.send(msgs, 0.1 * k, sent)
        got = radio.poll(0.1 * k + 0.05)
        for n in names:
            ref = [(d.message.sender, d.message.round, d.message.motions.tobytes(), d.duplicate)
                   for d in one.network.poll(n, 0.1 * k + 0.05)]
            assert [(d.message.sender, d.message.round, d.message.motions.tobytes(), d.duplicate)
                    for d in got[n]] == ref
    a, b = one.network.stats(), many.network.stats()
    assert a.total.as_dict() == b.total.as_dict()
    assert a.total.as_dict()["dropped"] > 0 and a.total.as_dict()["duplicated"] > 0
    assert sent.sum() == a.total.as_dict()["sent"]
