"""Valid documents the hostile cases start from (made once per session, tiny)."""

from __future__ import annotations

import copy

import numpy as np
import pytest


@pytest.fixture(scope="session")
def _simulated():
    from sims.io.log_json import log_to_dict
    from sims.simulation.scenarios import get_scenario, simulate
    from sims.simulation.world.truth import truth_to_dict

    sim = simulate(get_scenario("single_node", steps=4), seed=0)
    return log_to_dict(sim.log), truth_to_dict(sim.truth)


@pytest.fixture
def log_doc(_simulated):
    """A valid ``decentral.log/1`` document (observer A0 with camera cam0, target A1 with node 10; 4 steps)."""
    return copy.deepcopy(_simulated[0])


@pytest.fixture
def truth_doc(_simulated):
    """The ``decentral.truth/1`` document of the same run."""
    return copy.deepcopy(_simulated[1])


@pytest.fixture
def estimate_doc(_simulated):
    """A valid ``decentral.estimate/1`` document over the same step times."""
    times = [step["t"] for step in _simulated[0]["steps"]]
    return {"format": "decentral.estimate/1", "reference": "A0",
            "steps": [{"t": t, "poses": {"A1": {"p": [1.0, 0.0, 0.0], "theta": 0.1}}} for t in times], "stats": {}}


@pytest.fixture(scope="session")
def _ensemble():
    from sims.simulation.ensembles.generator import EnsembleSpec, generate
    from sims.simulation.ensembles.sensors import SensorModel

    ens = generate(EnsembleSpec("triple", 30, 0.05, "hcp", 0.03, SensorModel()), np.random.default_rng(0))
    return ens


@pytest.fixture
def ensemble_arrays(tmp_path_factory, _ensemble):
    """The arrays of a valid 30-module ``decentral.ensemble/1`` file, as a dict."""
    from sims.simulation.ensembles.generator import save_observations

    path = tmp_path_factory.mktemp("ens") / "obs.npz"
    save_observations(path, _ensemble)
    with np.load(path, allow_pickle=False) as data:
        return {k: data[k].copy() for k in data.files}
