"""The lag meter: one-way delays in rounds from message round stamps, the scale of an agent's waits."""

from __future__ import annotations

import numpy as np

from protocols.lag import LagMeter


def test_an_agent_that_heard_nothing_has_no_lag_and_no_round_trip():
    """Before any message arrived the lag is unknown: heard is False and the waits are not scaled (0)."""
    meter = LagMeter()
    assert not meter.heard and meter.one_way() == 0 and meter.typical() == 0 and meter.round_trip() == 0


def test_the_round_trip_covers_nine_lags_in_ten_twice_over():
    """Lags drawn from 6-14 rounds (a 200 ms link with jitter at 25 ms rounds): the one-way lag is at least the 90th
    percentile, the round trip at least twice that, the typical lag the median."""
    lags = np.random.default_rng(4).integers(6, 15, size=64)
    meter = LagMeter()
    for lag in lags:
        meter.observe(int(lag))
    assert meter.one_way() >= np.quantile(lags, 0.9) - 1e-9
    assert meter.round_trip() >= 2 * meter.one_way()
    assert abs(meter.typical() - np.median(lags)) <= 1


def test_a_link_that_got_faster_is_trusted_again():
    """Only the newest ``keep`` lags count: after 64 fast messages the slow ones are forgotten."""
    meter = LagMeter(keep=64)
    for _ in range(64):
        meter.observe(20)
    for _ in range(64):
        meter.observe(1)
    assert meter.one_way() == 1


def test_a_peer_slightly_ahead_counts_as_no_lag():
    """Negative lags (a peer whose round is a little ahead) count as 0, never as a negative wait."""
    meter = LagMeter()
    meter.observe(-3)
    assert meter.heard and meter.one_way() == 0
