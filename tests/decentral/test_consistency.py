"""The leave-one-out consistency test: honest data exclude no one, a member whose data the others contradict is found."""

from __future__ import annotations

import numpy as np

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
