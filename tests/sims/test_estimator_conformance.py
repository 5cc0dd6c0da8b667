"""Every estimator (the centralized ones and the decentralized runner) passes estimator_test."""

import dataclasses

import pytest

from decentral.bearing import estimate_log_bearing
from decentral.conformance import estimator_test
from decentral.estimator import EstimatorConfig, estimate_log
from sims.runners.admm_run import AdmmRunConfig, run_admm
from sims.cli.main import build_parser


def _admm(log, config=None, reference=None):
    return run_admm(log, reference, config or AdmmRunConfig()).estimate


#: every way `decentral localize` estimates (--estimator's choices and --mode admm) -> (callable, config)
IMPLEMENTATIONS = {
    "windowed": (estimate_log, EstimatorConfig(window=3)),
    "bearing": (estimate_log_bearing, None),
    "admm": (_admm, AdmmRunConfig(window=3)),
}


def test_every_estimator_is_checked():
    """Every estimator the CLI offers (and the decentralized mode) has a conformance case here."""
    sub = next(a for a in build_parser()._actions if a.dest == "command")
    estimators = next(a for a in sub.choices["localize"]._actions if "--estimator" in a.option_strings).choices
    assert set(IMPLEMENTATIONS) == set(estimators) | {"admm"}


@pytest.mark.parametrize("name", sorted(IMPLEMENTATIONS))
def test_estimator_conforms(name):
    """The estimator passes estimator_test (same stats keys, placements or reasons, accuracy, determinism)."""
    fn, config = IMPLEMENTATIONS[name]
    estimator_test(fn, config, name=name)


def test_estimator_test_refuses_missing_stats():
    """An estimator whose stats lack stray_detections fails estimator_test, naming the key."""
    def partial(log, config=None, reference=None):
        est = estimate_log(log, reference=reference)
        return dataclasses.replace(est, stats={k: v for k, v in est.stats.items() if k != "stray_detections"})

    with pytest.raises(AssertionError, match="stray_detections"):
        estimator_test(partial)


def test_estimator_test_refuses_a_crash_on_bad_input():
    """An estimator that crashes on a dict instead of a log fails estimator_test, naming the exception."""
    def careless(log, config=None, reference=None):
        return estimate_log(log.steps, reference=reference)  # AttributeError on a dict

    with pytest.raises(AssertionError, match="AttributeError"):
        estimator_test(careless)
