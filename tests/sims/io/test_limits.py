"""Resource limits: defaults, overrides by environment variable, and their documentation."""

from __future__ import annotations

from dataclasses import fields
from pathlib import Path

import pytest

from decentral.errors import InputError
from sims.io.limits import Limits, current_limits


def test_each_limit_is_raised_by_its_variable(monkeypatch):
    """Every limit reads DECENTRAL_<NAME>; unset variables keep the defaults."""
    assert current_limits() == Limits()
    for f in fields(Limits):
        monkeypatch.setenv(Limits.variable(f.name), "7")
        assert getattr(current_limits(), f.name) == 7


@pytest.mark.parametrize("raw", ["0", "-3", "nan", "inf", "lots", "2.5x"])
def test_bad_values_name_the_variable(raw, monkeypatch):
    """A limit variable must be a positive finite number; otherwise the error names it."""
    monkeypatch.setenv("DECENTRAL_MAX_PIXELS", raw)
    with pytest.raises(InputError, match="DECENTRAL_MAX_PIXELS"):
        current_limits()


def test_every_limit_is_documented():
    """The limits table of docs/robustness.md lists every variable with its default."""
    readme = (Path(__file__).resolve().parents[3] / "docs" / "robustness.md").read_text(encoding="utf-8")
    for f in fields(Limits):
        default = getattr(Limits(), f.name)
        row = f"| `{Limits.variable(f.name)}` | {int(default) if float(default).is_integer() else default} |"
        assert row in readme, row
