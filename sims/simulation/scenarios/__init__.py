"""Scenarios: one module per scenario, listed in an explicit registry.

``SCENARIOS`` maps a scenario's name to the module holding it; each module exposes its class as
``SCENARIO``. A test checks that the registry and the modules on disk agree.
"""

from __future__ import annotations

import importlib
from typing import Any

from decentral.errors import InputError
from sims.simulation.scenarios.base import Scenario, ScenarioConfig, Simulation, simulate

__all__ = ["SCENARIOS", "Scenario", "ScenarioConfig", "Simulation", "get_scenario", "simulate"]

#: scenario name -> module (each module defines ``SCENARIO``, a :class:`Scenario` subclass)
SCENARIOS: dict[str, str] = {
    "table1": "sims.simulation.scenarios.table1",
    "reconfig": "sims.simulation.scenarios.reconfig",
    "multi": "sims.simulation.scenarios.multi",
    "single_node": "sims.simulation.scenarios.single_node",
    "ring64": "sims.simulation.scenarios.ring64",
}


def get_scenario(name: str, **params: Any) -> Scenario:
    """Instantiate the scenario called ``name`` with ``params`` (unknown names or parameters raise)."""
    if name not in SCENARIOS:
        raise InputError(f"unknown scenario {name!r}; known: {', '.join(SCENARIOS)}", field="scenario")
    module = importlib.import_module(SCENARIOS[name])
    return module.SCENARIO(**params)
