"""The hierarchical localizer reports progress through a callback (the library never prints)."""

from __future__ import annotations

import numpy as np
import pytest

from decentral.ensemble.hierarchical import HierarchyConfig, normcut_localize


def test_progress_counts_every_module_once_and_announces_the_top(lattice, capsys):
    """Leaves report modules placed, monotonically up to n; the top refinement is announced; nothing printed."""
    problem, _, _ = lattice(2, (12, 10), noise=0.05)
    calls = []
    normcut_localize(problem, np.random.default_rng(0), HierarchyConfig(leaf_size=16),
                     progress=lambda done, total, **info: calls.append((done, total, info)))
    done = [c[0] for c in calls]
    assert done == sorted(done) and done[-1] == problem.n and all(c[1] == problem.n for c in calls)
    assert any(c[2]["stage"] == "top refinement" for c in calls)
    assert capsys.readouterr() == ("", "")


def test_with_tolerance_sets_every_refinement_and_rejects_nonsense():
    """with_tolerance changes the level and top gradient tolerances only; non-positive values raise."""
    base = HierarchyConfig()
    cfg = base.with_tolerance(0.02)
    assert cfg.level_refine.gtol == cfg.final_refine.gtol == 0.02
    assert cfg.final_refine.max_iter == base.final_refine.max_iter and cfg.leaf_size == base.leaf_size
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError):
            base.with_tolerance(bad)
