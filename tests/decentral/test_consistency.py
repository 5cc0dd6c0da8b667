"""The leave-one-out consistency test: honest data exclude no one, a member whose data the others contradict is found."""

from __future__ import annotations

import numpy as np
import pytest

from decentral.admm import quadratic_form, solve_joint
from decentral.consistency import residual, screen_members


def _ring(rng, lie=None, noise=0.01):
    """Four assemblies at known poses each seeing two nodes of every other; ``lie = (member, offset)`` shifts
    every detection that member makes by ``offset`` metres."""
    truth = {"A": (0.0, 0.0), "B": (3.0, 0.5), "C": (0.5, 3.0), "D": (-2.5, 1.0)}
    q = np.array([[0.0, 0.0, 0.0], [0.6, 0.0, 0.0]])
    forms = []
    for o, (ox, oy) in truth.items():
        for a, (ax, ay) in truth.items():
            if o == a:
                continue
            t = q + np.array([ax - ox, ay - oy, 0.0]) + noise * rng.standard_normal((2, 3))
            if lie is not None and o == lie[0]:
                t = t + np.array([lie[1], 0.0, 0.0])
            forms.append(quadratic_form([(o, 0), (a, 0)], visual=(np.zeros(2, int), np.ones(2, int), q, t,
                                                                  np.full(2, 1.0 / noise**2))))
    return forms


def test_honest_data_exclude_no_one():
    """Noisy but consistent data: nobody is excluded and the forms are kept as they came."""
    rng = np.random.default_rng(1)
    for _ in range(5):
        forms = _ring(rng)
        screening = screen_members(forms, ("A", 0))
        assert screening.excluded == () and len(screening.kept) == len(forms)


def test_the_screenings_solution_is_the_joint_solution_of_what_it_kept():
    """Nobody excluded: the screening hands over the whole window's solution, solve_joint's within 1e-9 (callers
    need not solve the same forms twice); a member excluded: no solution is handed over."""
    rng = np.random.default_rng(3)
    forms = _ring(rng)
    screening = screen_members(forms, ("A", 0))
    assert screening.excluded == () and screening.solution is not None
    direct = solve_joint(screening.kept, ("A", 0))
    assert set(screening.solution.poses) == set(direct.poses)
    for k, (R, p) in direct.poses.items():
        assert np.allclose(screening.solution.poses[k][0], R, atol=1e-9)
        assert np.allclose(screening.solution.poses[k][1], p, atol=1e-9)
    assert screen_members(_ring(rng, lie=("C", 0.5)), ("A", 0)).solution is None


def test_a_member_whose_detections_are_shifted_is_excluded_with_all_its_forms():
    """C reports every detection 0.5 m off: C is excluded, no kept form touches C, and the rest is consistent."""
    rng = np.random.default_rng(2)
    forms = _ring(rng, lie=("C", 0.5))
    screening = screen_members(forms, ("A", 0))
    assert screening.excluded == ("C",)
    assert all(k[0] != "C" for prob in screening.kept for k in prob.keys)
    left = residual(screening.kept, solve_joint(screening.kept, ("A", 0)).poses)
    assert left < 0.1 * screening.residual


def test_the_reference_is_never_excluded():
    """Even when the gauge's own data are the lie, the reference stays (someone else, or no one, is excluded)."""
    rng = np.random.default_rng(3)
    screening = screen_members(_ring(rng, lie=("A", 0.5)), ("A", 0))
    assert "A" not in screening.excluded


def _views(rng, at, pairs, lie=None, noise=0.01, dispersion=None):
    """Observer o sees target a's three nodes for each (o, a) in ``pairs``; ``lie = (member, offset)`` shifts
    every detection that member makes."""
    q = np.array([[0.0, 0.0, 0.0], [0.6, 0.0, 0.0], [0.0, 0.4, 0.0]])
    forms = []
    for o, a in pairs:
        t = q + [*np.subtract(at[a], at[o]), 0.0] + noise * rng.standard_normal((3, 3))
        if lie is not None and o == lie[0]:
            t = t + np.array([lie[1], 0.0, 0.0])
        forms.append(quadratic_form([(o, 0), (a, 0)], visual=(np.zeros(3, int), np.ones(3, int), q, t,
                                                              np.full(3, 1.0 / noise**2))))
    return forms


AT = {"A": (0.0, 0.0), "B": (3.0, 0.5), "C": (0.5, 3.0), "D": (-2.5, 1.0), "E": (1.0, -2.5)}


def test_with_calibrated_noise_a_members_statistic_has_the_chi_square_mean():
    """Gaussian detections with their true weights: over 200 draws each member's T averages its d (within 5 %)."""
    from decentral.consistency import member_tests

    rng = np.random.default_rng(4)
    pairs = [(o, a) for o in AT for a in AT if o != a]
    ratios = []
    for _ in range(200):
        forms = _views(rng, AT, pairs)
        tests = member_tests(forms, solve_joint(forms, ("A", 0)).poses)
        ratios.append([t / d for t, d, _ in tests.values()])
    assert abs(np.mean(ratios) - 1.0) < 0.05


@pytest.mark.parametrize("seed", range(5, 15))
def test_a_lie_every_other_member_checks_names_the_liar_by_the_chi_square_test(seed):
    """E's detections 10 cm off (10 sigma), seen by everyone: the margin test names no one, the chi-square test
    (calibrated noise, default level) names E, on every noise draw."""
    from decentral.consistency import screen_by_margin

    rng = np.random.default_rng(seed)
    pairs = [(o, a) for o in AT for a in AT if o != a]
    forms = _views(rng, AT, pairs, lie=("E", 0.1))
    assert screen_by_margin(forms, ("A", 0)).excluded == ()
    screening = screen_members(forms, ("A", 0), dispersion=1.0)
    assert screening.excluded == ("E",) and all(k[0] != "E" for prob in screening.kept for k in prob.keys)


def test_a_lie_only_one_member_checks_names_suspects_and_excludes_no_one():
    """D is seen by C alone and D sees only C, and D's views are 20 cm off: C and D are suspects, no one is excluded."""
    rng = np.random.default_rng(6)
    ring = [(o, a) for o in "ABC" for a in "ABC" if o != a] + [("C", "D"), ("D", "C")]
    screening = screen_members(_views(rng, AT, ring, lie=("D", 0.2)), ("A", 0), dispersion=1.0)
    assert screening.excluded == () and set(screening.suspects) == {"C", "D"}


def test_forms_without_measurement_counts_fall_back_to_the_margin_test():
    """Forms whose counts are unknown (0, an older peer) are screened by the residual margin, as before."""
    import dataclasses

    rng = np.random.default_rng(2)
    forms = [dataclasses.replace(f, count=0) for f in _ring(rng, lie=("C", 0.5))]
    screening = screen_members(forms, ("A", 0))
    assert screening.excluded == ("C",) and screening.tests == {}
