"""The Examples sections of the public entry points and of the conformance functions run as written."""

import doctest
import importlib

import pytest

#: modules whose docstring examples are part of the documentation
MODULES = [
    "decentral.estimator",
    "decentral.ensemble.hierarchical",
    "decentral.conformance",
    "sims.runners.admm_run",
    "sims.io.log_json",
    "agents.perception.conformance",
    "protocols.conformance",
]


@pytest.mark.parametrize("name", MODULES)
def test_examples_run(name):
    """Every example in the module's docstrings gives the printed output."""
    module = importlib.import_module(name)
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE, verbose=False)
    assert result.attempted > 0, f"{name} has no examples"
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples of {name} failed (see the output above)"
