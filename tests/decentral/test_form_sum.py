"""The window's forms summed once (FormSum): any subset's sum is the direct sum, its solve is solve_joint's,
its costs are the forms' own; and a noise-free window (residual zero up to rounding) is consistent."""

from __future__ import annotations

import numpy as np
import pytest

from decentral.admm import quadratic_form, solve_joint
from decentral.admm.form_sum import FormSum
from decentral.admm.joint import _joint_form
from decentral.consistency import screen_members
from sims.runners.admm_run import AdmmRunConfig, run_admm
from tests.decentral.test_attribution import _ring
from tests.decentral.test_placement import split_scene


def _drops(n_forms: int, seed: int, count: int = 12) -> list[set]:
    rng = np.random.default_rng(seed)
    return [set(rng.choice(n_forms, size=int(rng.integers(0, 15)), replace=False).tolist()) for _ in range(count)]


@pytest.mark.parametrize("seed", [0, 1])
def test_a_subsets_sum_is_the_forms_summed_one_by_one(seed):
    """form(drop) restricted to the gauge's component equals _joint_form of the kept forms exactly (same order of sums)."""
    forms = _ring(seed, n=6, sees=1)
    sums = FormSum(forms)
    n = len(sums.keys)
    for drop in _drops(len(forms), seed):
        keys, _, M, b_z = _joint_form([p for i, p in enumerate(forms) if i not in drop], ("A0", 0))
        comp = sums.component(("A0", 0), drop)
        cols = np.concatenate([comp, np.stack([n + 2 * comp, n + 2 * comp + 1], 1).ravel()])
        M_all, b_all = sums.form(drop)
        assert [sums.keys[i] for i in comp] == keys
        assert np.array_equal(M_all[np.ix_(cols, cols)], M) and np.array_equal(b_all[comp], b_z)


def test_a_subsets_solve_is_solve_joints_and_costs_are_the_forms_own():
    """The subset's poses are solve_joint's (1e-9; started from the whole window's yaws, Newton stops within 1e-5 of
    the same certified optimum, at the same residual to 1e-9 relative); each form's cost is LocalProblem.cost
    (1e-9 of the form's scale), NaN exactly for the forms the solution does not tie."""
    forms = _ring(2, n=6, sees=1)
    sums = FormSum(forms)
    whole = sums.solve(("A0", 0))
    for drop in _drops(len(forms), 2):
        rest = [p for i, p in enumerate(forms) if i not in drop]
        try:
            direct = solve_joint(rest, ("A0", 0))
        except np.linalg.LinAlgError:
            continue
        for warm, tol in ((None, 1e-9), (whole, 1e-5)):
            mine = sums.solve(("A0", 0), drop=drop, warm=warm)
            assert set(mine.poses) == set(direct.poses)
            for k, (R, p) in direct.poses.items():
                assert np.allclose(mine.poses[k][0], R, atol=tol) and np.allclose(mine.poses[k][1], p, atol=tol)
            left = sums.residual(mine.poses, drop)
            assert abs(left - sums.residual(direct.poses, drop)) <= 1e-9 * max(left, 1.0)
        costs = sums.costs(direct.poses)
        for i, prob in enumerate(forms):
            if all(k in direct.poses for k in prob.keys):
                theta = np.array([np.arctan2(direct.poses[k][0][1, 0], direct.poses[k][0][0, 0]) for k in prob.keys])
                own = prob.cost(theta, np.array([direct.poses[k][1] for k in prob.keys]))
                assert abs(costs[i] - own) <= 1e-9 * max(1.0, np.abs(prob.M).max())
            else:
                assert np.isnan(costs[i])


def test_a_noise_free_window_is_consistent():
    """Exact views leave a residual of zero up to rounding, sometimes just below zero: every member's p-value is
    a number, and the agents exclude and suspect no one (the split scene: one exact view per pair)."""
    q = np.array([[0.0, 0, 0], [0.6, 0, 0], [0.0, 0.4, 0]])
    at = {"A0": (0.0, 0.0), "A1": (2.3, 0.1), "A2": (0.4, 2.9)}
    forms = [quadratic_form([(o, 0), (a, 0)], visual=(np.zeros(3, int), np.ones(3, int), q,
                                                      q + [*np.subtract(at[a], at[o]), 0.0], np.full(3, 2e4)))
             for o in at for a in at if o != a]
    screening = screen_members(forms, ("A0", 0))
    assert screening.tests and all(np.isfinite(p) for _, _, p in screening.tests.values())
    assert screening.excluded == () and screening.suspects == ()
    estimate = run_admm(split_scene(), config=AdmmRunConfig(window=3, max_rounds=30)).estimate
    assert not estimate.stats.get("excluded") and not estimate.stats.get("suspects")
