r"""Consistency of the members' data: the member whose data the others contradict, found by a chi-square test.

Every member's data enter a window as quadratic cost forms over ``(assembly, step)`` poses: its own
odometry chain and the pairs it observes (a form's first key is its owner's), the latter built with
the observed member's announced configuration. The forms are information-weighted (each residual
divided by its standard deviation, :class:`decentral.noise.NoiseModel`), so at the joint optimum
the cost of a member's forms is a sum of squared whitened residuals: with honest data it is close to
chi-square distributed with as many degrees of freedom as the member's scalar measurements (3 per
detection, 4 per odometry link: :attr:`decentral.admm.LocalProblem.count`, shipped with the forms)
less its share of the parameters that the optimum fits. :func:`member_tests` computes the
statistic and its p-value for every member; :func:`screen_members` applies it leave-one-out: a
member is excluded when some member's statistic is out of bounds and removing its data (every form
over one of its poses) is the *only* removal that brings every other member's statistic back within
bounds. A lie (detections shifted, odometry scaled, a layout stretched, another's node ids claimed)
shows in the forms of every member that checks the liar; removing anyone but the liar leaves some
of them. :func:`screen_by_margin` is the earlier test on the ratio of leave-one-out residuals, used
when the measurement counts are unknown.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Hashable, Sequence

import numpy as np
from scipy.special import chdtrc  # the chi-square survival function (scipy.stats costs 0.5 s more to import)

from decentral.admm import JointSolution, LocalProblem
from decentral.admm.form_sum import FormSum
from decentral.attribution import attribute, optimum_residual

#: per-window false-alarm probability of the chi-square test (Bonferroni-divided over the members tested): at
#: 1e-3 an honest 4-ring had a member excluded once in 160 windows (seed 28, T/d 5.5), a false exclusion every
#: few minutes of a 10 Hz swarm; 1e-4 still names every lie of the tests (a 10-sigma detection shift seen
#: by every other member on every noise draw; 5 sigma was named on one draw in three even at 1e-3)
ALPHA = 1e-4
#: variance inflation c of the whitened residuals (see :func:`member_tests`). Calibrated residuals give c = 1,
#: and the isotropic detection weights (:func:`decentral.factors.detection_weights`, error mostly along the
#: viewing ray) at most c = 3; the simulator's sensors depart further from the weighting model (odometry
#: noise proportional to motion, occluded nodes 3x noisier), and honest members reach T/d = 6 on a
#: window. 12 is the smallest value of 3, 5, 6, 8, 10, 12 that raised no alarm on honest 5-assembly
#: logs (seeds 1-20, 240 windows); it holds on seeds 21-40 (tests/sims/runners/test_lies_simulated.py)
DISPERSION = 12.0

__all__ = ["Screening", "member_tests", "residual", "screen_by_margin", "screen_members", "without_members"]


def residual(problems: Sequence[LocalProblem], poses: dict) -> float:
    """Sum of the costs of ``problems`` at ``poses`` (key -> ``(R (2, 2), p (3,))``); forms over a key that
    ``poses`` lacks are left out (they are not tied to the solution)."""
    return FormSum(problems).residual(poses)


def _owner(prob: LocalProblem):
    return prob.keys[0][0]


def member_tests(problems: Sequence[LocalProblem], poses: dict, *, pose_dof: int = 4, gauges: int = 1,
                 dispersion: float = DISPERSION) -> dict:
    r"""Per member, the chi-square statistic of its forms at ``poses`` (the joint optimum of ``problems``).

    With :math:`m_g` the scalar measurements of member :math:`g`'s forms (:attr:`LocalProblem.count`),
    :math:`m = \sum_g m_g`, and :math:`p = \text{pose\_dof}\,(n - \text{gauges})` the parameters the
    optimum fits (``n`` poses, 4 degrees of freedom each: position and yaw), member :math:`g` gets

    .. math:: T_g = \sum_{f \in g} \mathrm{cost}_f(\hat x), \qquad
              d_g = m_g \,(1 - p / m), \qquad \mathrm{p}_g = P(\chi^2_{d_g} > T_g),

    its share of the fitted parameters taken in proportion to its measurements (the exact share, the
    trace of its block of the hat matrix, needs the Jacobians the forms have summed away; over a
    window the two differ by a few degrees of freedom against hundreds). Honest data give
    :math:`E[T_g] \approx d_g`.

    Parameters
    ----------
    problems : sequence of LocalProblem
        The forms (owner: the assembly of each form's first key).
    poses : dict
        ``(assembly, step)`` -> ``(R (2, 2), p (3,))``: the optimum of ``problems``.
    pose_dof, gauges : int
        Degrees of freedom per pose, and poses held fixed.
    dispersion : float
        Variance inflation :math:`c` of the whitened residuals (1: calibrated Gaussian).

    Returns
    -------
    dict
        Member -> ``(T, d, p_value)``; members whose forms hold no measurement are left out.
    """
    return _member_tests(FormSum(problems), frozenset(), poses, pose_dof=pose_dof, gauges=gauges,
                         dispersion=dispersion)


def _member_tests(sums: FormSum, drop: frozenset, poses: dict, *, pose_dof: int = 4, gauges: int = 1,
                  dispersion: float = DISPERSION) -> dict:
    """:func:`member_tests` of the forms of ``sums`` not in ``drop``."""
    costs = sums.costs(poses)
    stat: dict = {}
    keys: set = set()
    for i, prob in enumerate(sums.problems):
        if i in drop:
            continue
        keys.update(k for k in prob.keys if k in poses)
        t, m = stat.get(_owner(prob), (0.0, 0))
        stat[_owner(prob)] = (t + (0.0 if np.isnan(costs[i]) else float(costs[i])), m + int(prob.count))
    n = len(keys)
    total = sum(m for _, m in stat.values())
    share = 1.0 - min(pose_dof * max(n - gauges, 0) / total, 0.9) if total else 1.0
    out = {}
    for owner, (t, m) in stat.items():
        if m > 0:
            d = max(m * share, 1.0)
            # (t < 0 is the rounding of a sum of squares: chdtrc gives NaN there)
            out[owner] = (t, d, float(chdtrc(d / dispersion, max(t, 0.0) / dispersion)))
    return out


def _within(tests: dict, alpha: float) -> bool:
    return all(p > alpha / max(len(tests), 1) for _, _, p in tests.values())


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
        Candidate -> what removing it left: for the chi-square test, the smallest p-value (times the
        number of members tested) of the others' statistics at their own optimum; for the margin
        test, the others' residual. In the last round of the test.
    tests : dict
        Member -> ``(T, d, p_value)`` of all the forms at their joint optimum (:func:`member_tests`; empty
        for the margin test).
    suspects : tuple
        When the data stay inconsistent and several members' removals each explain it (a lie that only
        one member checks): those members, none of them excluded.
    solution : JointSolution or None
        The joint solution of ``kept`` where the screening already computed it (nobody excluded: the
        whole window's, as :func:`decentral.admm.solve_joint` gives it within 1e-9), so the caller need
        not solve the same forms again; None otherwise.
    """

    excluded: tuple
    kept: list
    residual: float
    left: dict = field(default_factory=dict)
    tests: dict = field(default_factory=dict)
    suspects: tuple = ()
    solution: JointSolution | None = None


def screen_by_margin(problems: Sequence[LocalProblem] | FormSum, gauge: tuple, value=None, *, ratio: float = 10.0,
                   floor: float = 100.0, max_excluded: int | None = None) -> Screening:
    r"""Remove the members whose data the others' contradict (leave-one-out residual margin test).

    The test :func:`screen_members` falls back to when some form's measurement count is unknown
    (``count == 0`` with data: forms from a peer that does not send counts).

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
    problems : sequence of LocalProblem, or FormSum
        The window's forms over ``(member, step)`` keys (or a :class:`decentral.admm.form_sum.FormSum` of them).
    gauge : tuple
        The gauge key ``(reference, step)``; the reference is never a candidate.
    value : (R, p), optional
        The gauge's value (identity by default).
    ratio, floor : float
        The test's thresholds (dimensionless; residual units).
    max_excluded : int, optional
        At most this many members are removed.

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
    >>> screen_by_margin(forms, ("A", 0), floor=1.0).excluded
    ('C',)
    """
    sums = problems if isinstance(problems, FormSum) else FormSum(problems)
    problems = sums.problems
    members = sorted({k[0] for prob in problems for k in prob.keys} - {gauge[0]}, key=repr)
    limit = max(0, (len(members) + 1 - 1) // 2) if max_excluded is None else int(max_excluded)
    excluded: list[Hashable] = []
    whole = sums.solve(gauge, value)
    first_total = sums.residual(whole.poses)
    dropped: frozenset = frozenset()
    left: dict = {}
    while len(excluded) < limit:
        candidates = [a for a in members if a not in excluded]
        if len(candidates) < 2:
            break
        left, rests = {}, {}
        for a in candidates:
            rests[a] = dropped | _over(problems, a)
            try:
                left[a] = optimum_residual(sums, gauge, value, rests[a], warm=whole)
            except np.linalg.LinAlgError:  # the rest does not tie its variables: no verdict on this member
                left[a] = np.inf
        order = sorted(candidates, key=lambda a: (left[a], repr(a)))
        best, second = left[order[0]], left[order[1]]
        if not (np.isfinite(best) and second > ratio * best and second - best > floor):
            break
        excluded.append(order[0])
        dropped = rests[order[0]]
    return Screening(tuple(excluded), _without(problems, dropped), first_total, left)


def _over(problems: Sequence[LocalProblem], member) -> frozenset:
    """Indices of the forms over some pose of ``member``."""
    return frozenset(i for i, prob in enumerate(problems) if any(k[0] == member for k in prob.keys))


def _without(problems: Sequence[LocalProblem], drop: frozenset) -> list:
    return [prob for i, prob in enumerate(problems) if i not in drop]


def without_members(problems: Sequence[LocalProblem], members) -> list:
    """The forms of ``problems`` over no pose of any of ``members`` (what is left once they are excluded)."""
    drop = frozenset().union(*(_over(problems, m) for m in members))
    return _without(problems, drop)


def screen_members(problems: Sequence[LocalProblem], gauge: tuple, value=None, *, alpha: float = ALPHA,
                   dispersion: float = DISPERSION, max_excluded: int | None = None,
                   classes: bool = True) -> Screening:
    r"""Remove the member whose data the others contradict: the chi-square test of :func:`member_tests`, leave-one-out.

    The forms are solved jointly and every member's statistic tested at level ``alpha / G``
    (Bonferroni over the ``G`` members with measurements: with honest data a window raises a false
    alarm with probability at most about ``alpha``). The residual margin test (:func:`screen_by_margin`,
    one solve per member) runs only on a window that fails, before the chi-square rounds: a lie far
    above the noise fails it too. When some member fails, each member ``a`` other
    than the gauge's is tried: the forms over any pose of ``a`` are removed, the rest solved, and
    every remaining member tested again (at ``alpha / (G - 1)``). The removals that bring every other
    member within bounds *explain* the inconsistency (in the manner of pairwise consistency
    maximization, Mangelson et al. 2018, with members for measurements); when exactly one does, it
    is the liar: it is excluded and the test runs again on what is left (at most ``max_excluded``
    members, by default fewer than half). When none does (two liars) or several do (a lie that only
    one other member checks is explained as well by removing that checker), no one is excluded:
    the data are inconsistent but the liar cannot be named (``suspects``).

    Falls back to :func:`screen_by_margin` when some form with data has an unknown measurement count
    (``count == 0``).

    Parameters
    ----------
    problems : sequence of LocalProblem
        The window's forms over ``(member, step)`` keys, with their measurement counts.
    gauge : tuple
        The gauge key ``(reference, step)``; the reference is never a candidate.
    value : (R, p), optional
        The gauge's value (identity by default).
    alpha : float
        False-alarm probability per window and round of the test.
    dispersion : float
        Variance inflation of the whitened residuals (:func:`member_tests`; 1 for calibrated Gaussian noise).
    max_excluded : int, optional
        At most this many members are removed.
    classes : bool
        Run the class-by-class tests (:func:`decentral.attribution.attribute`, about 3 solves per member) when
        the member-wide tests name no one. The agents skip them in broadcast windows after the cold start,
        where every agent solves the window itself: on an 8-ring over 200 ms links their CPU at every agent
        left 61 % placed instead of 100 %.

    Returns
    -------
    Screening
        The excluded members, the forms kept, and the members' statistics on all the forms.

    Examples
    --------
    >>> from decentral.admm import quadratic_form
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> at = {"A": (0.0, 0.0), "B": (3.0, 0.5), "C": (0.5, 3.0), "D": (-2.5, 1.0)}
    >>> q = np.array([[0.0, 0, 0], [0.6, 0, 0], [0.0, 0.4, 0]])
    >>> def seen(o, a, lie=0.0):  # o sees a's three nodes (1 cm noise); a liar's views are off by `lie` m
    ...     t = q + [*np.subtract(at[a], at[o]), 0.0] + 0.01 * rng.standard_normal((3, 3)) + [lie, 0, 0]
    ...     return quadratic_form([(o, 0), (a, 0)], visual=(np.zeros(3, int), np.ones(3, int), q, t,
    ...                                                     np.full(3, 1e4)))
    >>> honest = [seen(o, a) for o in at for a in at if o != a]
    >>> screen_members(honest, ("A", 0), dispersion=1.0).excluded
    ()
    >>> lying = [seen(o, a, 0.1 if o == "C" else 0.0) for o in at for a in at if o != a]
    >>> screen_members(lying, ("A", 0), dispersion=1.0).excluded
    ('C',)
    """
    if any(prob.count <= 0 and np.any(prob.M) for prob in problems):
        return screen_by_margin(problems, gauge, value, max_excluded=max_excluded)
    sums = FormSum(problems)
    problems = sums.problems
    whole = sums.solve(gauge, value)
    first_total, first_tests = sums.residual(whole.poses), _member_tests(sums, frozenset(), whole.poses,
                                                                        dispersion=dispersion)
    if not _within(first_tests, alpha):  # (a consistent window skips the leave-one-out margin test: N solves)
        margin = screen_by_margin(sums, gauge, value, max_excluded=max_excluded)  # (the forms already laid out)
        if margin.excluded:  # a lie far above the noise: named by the residual margin
            return margin
    members = sorted({k[0] for prob in problems for k in prob.keys} - {gauge[0]}, key=repr)
    limit = max(0, len(members) // 2) if max_excluded is None else int(max_excluded)
    excluded: list[Hashable] = []
    left: dict = {}
    tests, suspects, dropped = first_tests, (), frozenset()
    while len(excluded) < limit and not _within(tests, alpha):
        candidates = [a for a in members if a not in excluded]
        left, rests, tested, untied = {}, {}, {}, []
        for a in candidates:
            rest = dropped | _over(problems, a)
            try:
                rest_poses = sums.solve(gauge, value, rest, warm=whole).poses if len(rest) < len(sums) else {}
            except np.linalg.LinAlgError:  # the rest does not tie its variables: a may be the liar or not
                untied.append(a)
                continue
            rests[a] = rest
            tested[a] = _member_tests(sums, rest, rest_poses, dispersion=dispersion)
            left[a] = min((p * max(len(tested[a]), 1) for _, _, p in tested[a].values()), default=1.0)
        explaining = sorted((a for a in left if left[a] > alpha), key=repr)
        if len(explaining) != 1 or untied:
            # no single removal explains it (two liars), or several do or may (a lie that only one other member
            # checks is explained as well by removing that checker, whose removal may leave the liar untied)
            suspects = tuple(sorted(explaining + untied, key=repr)) if explaining else ()
            break
        liar = explaining[0]
        excluded.append(liar)
        dropped, tests = rests[liar], tested[liar]
    kept = _without(problems, dropped)
    if classes and not excluded and len(members) >= 2 and limit >= 1:
        # the omnibus test is blind to a lie in one class of a member's data (a view turned, odometry scaled, a
        # layout stretched) that its other data dilute: test each class against the rest
        found = attribute(sums, gauge, value)  # (kept: every form, nobody was excluded)
        if found.liar is not None:
            excluded, suspects = [found.liar], ()
            kept = _without(problems, _over(problems, found.liar))
        elif found.suspects and not suspects:
            suspects = found.suspects
    solution = whole if not excluded else None
    return Screening(tuple(excluded), kept, first_total, left, first_tests, suspects, solution)
