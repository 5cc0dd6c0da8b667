"""The scenario registry and the scenario configs."""

from pathlib import Path

import pytest

import sims.simulation.scenarios as scenarios
from decentral.errors import InputError
from sims.simulation.scenarios import SCENARIOS, get_scenario
from sims.simulation.scenarios.base import Scenario

#: modules of sims/simulation/scenarios that hold shared machinery, not a scenario
HELPERS = {"__init__", "base", "output"}


def test_registry_matches_the_modules_on_disk():
    """Every scenario module is registered under its own name, and every registered one exists."""
    folder = Path(scenarios.__file__).parent
    on_disk = {p.stem for p in folder.glob("*.py")} - HELPERS
    assert on_disk == set(SCENARIOS)
    for name, module in SCENARIOS.items():
        assert module == f"sims.simulation.scenarios.{name}"


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_each_module_exposes_its_scenario_class(name):
    """SCENARIO in each module is a Scenario subclass whose name is the registry key."""
    scenario = get_scenario(name)
    assert isinstance(scenario, Scenario) and scenario.name == name


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_unknown_parameters_raise(name):
    """A parameter the scenario does not have is bad input naming it."""
    with pytest.raises(InputError, match="no_such_knob"):
        get_scenario(name, no_such_knob=1)


def test_wrongly_typed_parameter_names_the_field():
    """A parameter of the wrong type is bad input naming that parameter."""
    with pytest.raises(InputError) as err:
        get_scenario("multi", n_assemblies="many")
    assert err.value.field == "n_assemblies"


def test_out_of_range_parameter_is_bad_input():
    """A ring of 100 assemblies is refused (2-64)."""
    with pytest.raises(InputError):
        get_scenario("multi", n_assemblies=100)


def test_unknown_scenario_is_bad_input():
    """An unknown scenario name is bad input listing the known ones."""
    with pytest.raises(InputError, match="table1"):
        get_scenario("nope")


def test_configs_are_frozen():
    """Scenario configs cannot be changed after construction."""
    config = get_scenario("table1").config
    with pytest.raises(AttributeError):
        config.steps = 3


def test_unknown_shape_name_is_bad_input():
    """A table1 target shape that is not in the library is bad input, not a crash later."""
    with pytest.raises(InputError, match="blob"):
        get_scenario("table1", target_shapes=["L", "blob", "T"])
