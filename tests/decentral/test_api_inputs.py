"""Public entry points that take a log or an estimate accept only what they document: anything else is an
InputError naming the field, never an AttributeError from deep inside."""

from dataclasses import replace

import numpy as np
import pytest

from decentral.bearing import estimate_log_bearing
from decentral.errors import InputError
from decentral.estimator import EstimatorConfig, estimate_log
from decentral.metrics import estimate_gap, score_estimate
from decentral.observations import Step
from sims.runners.admm_run import run_admm
from sims.io.log_json import estimate_to_dict, log_to_dict
from sims.io.trajectories import estimate_trajectories
from tests.synthetic import camera, circle_motion, l_config, line_config, make_log

LOG_TAKERS = [estimate_log, estimate_log_bearing, run_admm, log_to_dict]


@pytest.fixture(scope="module")
def log():
    world = {"A0": [(0.0, np.array([0.02 * k, 0.0, 0.81])) for k in range(4)],
             "A1": circle_motion(4, (2.0, 0.0), 0.3, 0.0, 0.05, 0.06)}
    return make_log(world, {"A0": line_config([0, 1]), "A1": l_config([5, 6, 7])}, [camera("A0")])


@pytest.mark.parametrize("call", LOG_TAKERS, ids=lambda f: f.__name__)
def test_a_json_dict_is_refused_with_a_pointer_to_the_reader(call, log):
    """A decoded decentral.log/1 dict is an InputError that names read_log/parse_log."""
    with pytest.raises(InputError, match="parse_log"):
        call(log_to_dict(log))


@pytest.mark.parametrize("call", LOG_TAKERS, ids=lambda f: f.__name__)
def test_malformed_logs_name_the_field(call, log):
    """Lists instead of arrays, decreasing times, an unknown reference: InputError with the field path."""
    bad_centre = replace(log, steps=(replace(log.steps[0], config={"A0": {0: [0, 0, 0]}}), *log.steps[1:]))
    with pytest.raises(InputError, match=r"steps\[0\]\.config\.A0\.0"):
        call(bad_centre)
    backwards = replace(log, steps=(log.steps[1], log.steps[0]))
    with pytest.raises(InputError, match=r"steps\[1\]\.t"):
        call(backwards)
    stranger = replace(log, steps=(Step(0.0, {"A9": {}}),))
    with pytest.raises(InputError, match="config.A9"):
        call(stranger)


def test_wrong_config_and_reference_are_input_errors(log):
    """A config of the wrong class or a reference that is not an assembly is refused as input."""
    with pytest.raises(InputError, match="EstimatorConfig"):
        estimate_log(log, {"window": 5})
    with pytest.raises(InputError, match="reference"):
        estimate_log(log, EstimatorConfig(), reference=3)
    with pytest.raises(InputError, match="reference"):
        run_admm(log, reference="A7")


def test_estimate_takers_refuse_dicts(log):
    """score_estimate, estimate_gap, estimate_to_dict and the exporters want an Estimate, not its JSON."""
    est = estimate_log(log, EstimatorConfig(window=2))
    doc = estimate_to_dict(est)
    for call in (lambda: estimate_to_dict(doc), lambda: estimate_gap(doc, est), lambda: estimate_trajectories(doc)):
        with pytest.raises(InputError, match="parse_estimate"):
            call()
    with pytest.raises(InputError, match="GroundTruth"):
        score_estimate({"A0": []}, est)
