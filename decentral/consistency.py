"""Consistency of the members' data: the member whose data the others contradict, found from residuals.

Every member's data enters a window as quadratic cost forms over ``(assembly, step)`` poses (its
own odometry chain, the pairs it observes, and the pairs in which others observe it, built with
its announced configuration). Consistent data leave small residuals at the joint optimum. A member
that lies (detections shifted, odometry scaled, a layout stretched, another's node ids claimed)
leaves a residual that does not go away: removing *its* data (every form over one of its poses)
drops the joint residual far more than removing anyone else's. :func:`screen_members` is that
leave-one-out test, in the manner of pairwise consistency maximization (Mangelson et al. 2018):
each candidate's removal is tried, and the member whose removal takes the residual from
inconsistent to consistent is excluded.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Hashable, Sequence

import numpy as np

from decentral.admm import LocalProblem, solve_joint

__all__ = ["Screening", "residual", "screen_members"]


def residual(problems: Sequence[LocalProblem], poses: dict) -> float:
    """Sum of the costs of ``problems`` at ``poses`` (key -> ``(R (2, 2), p (3,))``); forms over a key that
    ``poses`` lacks are left out (they are not tied to the solution)."""
    total = 0.0
    for prob in problems:
        if not all(k in poses for k in prob.keys):
            continue
        theta = np.array([np.arctan2(poses[k][0][1, 0], poses[k][0][0, 0]) for k in prob.keys])
        position = np.array([np.asarray(poses[k][1], float) for k in prob.keys])
        total += prob.cost(theta, position)
    return float(total)


@dataclass(frozen=True)
class Screening:
    """What :func:`screen_members` found.

    Attributes
    ----------
    excluded : tuple
        Members whose data were removed, in the order they were found.
    kept : list of LocalProblem
        The forms left (none of them over an excluded member's pose).
    residual : float
        Joint residual of all the forms at their optimum.
    left : dict
        Candidate -> residual of the others' forms at their own optimum, in the last round of the test.
    """

    excluded: tuple
    kept: list
    residual: float
    left: dict = field(default_factory=dict)


def screen_members(problems: Sequence[LocalProblem], gauge: tuple, value=None, *, ratio: float = 10.0,
                   floor: float = 100.0, max_excluded: int | None = None,
                   solve: Callable = solve_joint) -> Screening:
    r"""Remove the members whose data the others' contradict (leave-one-out residual test).

    For each member ``a`` other than the gauge's, the forms over any pose of ``a`` are removed and
    the rest solved (:func:`decentral.admm.solve_joint`); ``left[a]`` is the residual the others'
    forms leave at their own optimum. A liar's data contradict every form they enter, so removing
    them leaves a consistent rest, while removing anyone else's leaves (some of) the lie. The member
    with the smallest ``left`` is excluded when the next smallest is far above it:

    .. math:: \mathrm{left}_{(2)} > \mathrm{ratio} \cdot \mathrm{left}_{(1)}
              \quad\text{and}\quad \mathrm{left}_{(2)} - \mathrm{left}_{(1)} > \mathrm{floor},

    and the test is run again on what is left (one member per round, at most ``max_excluded``, by
    default fewer than half of the members). Residuals are sums of squared errors weighted by their
    information, so consistent data leave a residual of the order of their number of measurements
    whoever is removed, and a lie adds a residual that grows with its square. A lie that only one
    pair of members shares (a single contradicted form) cannot be pinned on either and excludes no one.

    Parameters
    ----------
    problems : sequence of LocalProblem
        The window's forms over ``(member, step)`` keys.
    gauge : tuple
        The gauge key ``(reference, step)``; the reference is never a candidate.
    value : (R, p), optional
        The gauge's value (identity by default).
    ratio, floor : float
        The test's thresholds (dimensionless; residual units).
    max_excluded : int, optional
        At most this many members are removed.
    solve : callable
        ``solve(problems, gauge, value)`` with a ``poses`` attribute (default :func:`solve_joint`).

    Returns
    -------
    Screening
        The excluded members and the forms kept.

    Examples
    --------
    >>> from decentral.admm import quadratic_form
    >>> import numpy as np
    >>> def seen(o, a, q, t):  # observer o sees a's node at q (in a's frame) at t (in o's frame)
    ...     return quadratic_form([(o, 0), (a, 0)], visual=(np.array([0, 0]), np.array([1, 1]),
    ...                           np.array(q, float), np.array(t, float), np.ones(2)))
    >>> q = [[0.0, 0, 0], [1.0, 0, 0]]
    >>> forms = [seen("A", "B", q, [[2.0, 0, 0], [3, 0, 0]]), seen("A", "C", q, [[0, 2.0, 0], [1, 2, 0]]),
    ...          seen("B", "C", q, [[-2.0, 2, 0], [-1, 2, 0]]), seen("A", "D", q, [[0, -2.0, 0], [1, -2, 0]]),
    ...          seen("B", "D", q, [[-2.0, -2, 0], [-1, -2, 0]]),
    ...          seen("C", "D", q, [[0, -40.0, 0], [1, -40, 0]]),  # C's views are lies
    ...          seen("C", "B", q, [[30.0, 0, 0], [31, 0, 0]])]
    >>> screen_members(forms, ("A", 0), floor=1.0).excluded
    ('C',)
    """
    kept = list(problems)
    members = sorted({k[0] for prob in kept for k in prob.keys} - {gauge[0]}, key=repr)
    limit = max(0, (len(members) + 1 - 1) // 2) if max_excluded is None else int(max_excluded)
    excluded: list[Hashable] = []
    first_total = residual(kept, solve(kept, gauge, value).poses)
    left: dict = {}
    while len(excluded) < limit:
        candidates = [a for a in members if a not in excluded]
        if len(candidates) < 2:
            break
        left, rests = {}, {}
        for a in candidates:
            rest = [p for p in kept if all(k[0] != a for k in p.keys)]
            rests[a] = rest
            try:
                left[a] = residual(rest, solve(rest, gauge, value).poses) if rest else 0.0
            except np.linalg.LinAlgError:  # the rest does not tie its variables: no verdict on this member
                left[a] = np.inf
        order = sorted(candidates, key=lambda a: (left[a], repr(a)))
        best, second = left[order[0]], left[order[1]]
        if not (np.isfinite(best) and second > ratio * best and second - best > floor):
            break
        excluded.append(order[0])
        kept = rests[order[0]]
    return Screening(tuple(excluded), kept, first_total, left)
