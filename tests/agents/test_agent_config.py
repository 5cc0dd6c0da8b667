"""What an agent is told when it starts: AgentConfig refuses what no agent could run with."""

import pytest

from agents.agent_config import AgentConfig
from decentral.errors import InputError

NAMES = ("A0", "A1", "A2")


@pytest.mark.parametrize("field, value", [("window", 0), ("window", 2.5), ("announce_every", 0),
                                          ("share_forms", "sometimes"), ("aggregation", "gossip")])
def test_bad_parameters_are_refused_naming_the_field(field, value):
    """A window below 1, a non-positive announce period or an unknown mode raises InputError naming the field."""
    with pytest.raises(InputError) as err:
        AgentConfig(name="A1", assemblies=NAMES, reference="A0", **{field: value})
    assert err.value.field == field


def test_the_reference_must_be_one_of_the_assemblies():
    """A reference outside the assembly list is refused."""
    with pytest.raises(InputError):
        AgentConfig(name="A1", assemblies=NAMES, reference="B9")
