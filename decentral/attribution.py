r"""Which of a member's data the others contradict: its detections, its odometry or its layout.

A member's data enter a window's forms in three classes (:func:`data_of`):

- ``detections``: the pair forms it owns (its views of the others, first key its own, second another's);
- ``odometry``: the forms over its own poses only (its odometry links);
- ``layout``: the pair forms *others* own that target it, built with the configuration it announced.

A lie changes one class: detections shifted (a view rotated about its camera), odometry scaled (its
links), a layout stretched (every view of it). For each class :math:`h` of each member the forms of
:math:`h` are removed and the rest solved again; the drop of the joint residual per scalar measurement
of :math:`h`,

.. math:: e_h = \frac{T(\text{all}) - T(\text{all} \setminus h)}{m_h},

is how far :math:`h` disagrees with what the rest implies (for a linear Gaussian model it is the
innovation test of :math:`h` against the rest: :math:`E[e_h] \approx 1` for calibrated, consistent data;
the simulator's sensors depart from the isotropic weighting model, so honest classes reach a few
units, see :data:`THRESHOLD`). This is the pairwise-consistency idea of PCM (Mangelson et al. 2018)
with classes of a member's data for measurements, and it sees the cycles of the view graph: a view
in a ring of observers is checked by the other way round the ring.

:func:`attribute` names a liar when the classes above :data:`THRESHOLD` are explained by one member:
some class of that member whose removal leaves every other class within bounds, and no other member's
class that does. A layout lie is also in the views of its observers (their ``detections`` class); when
it is seen by one observer only, that observer's removal explains it as well, and both are suspects.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Hashable, Sequence

import numpy as np

from decentral.admm import JointSolution, LocalProblem
from decentral.admm.form_sum import FormSum

__all__ = ["CLASSES", "MARGIN", "MIN_COUNT", "THRESHOLD", "Attribution", "attribute", "class_excess", "data_of",
           "optimum_residual"]

#: the classes of a member's data
CLASSES = ("detections", "odometry", "layout")
#: excess residual per measurement above which a class is inconsistent with the rest (see
#: :func:`class_excess`); honest 4-6 assembly logs reach 4.5 (seeds 1-20, every window), see docs/robustness.md
THRESHOLD = 6.0
#: fewest scalar measurements an odometry class needs to be tested (4 links): the excess of one or two links
#: scatters too widely (an honest 6-assembly log gave 6.5 on the first window's links). Views are tested from
#: their first step (a layout lie must be named in the first window for that step to be exact)
MIN_COUNT = 16
#: margin, in standard deviations, by which one explanation must leave less residual than another (:func:`attribute`);
#: the layout-or-observer comparison on honest data reached 5.5 (seeds 1-20, 5 assemblies, 211 observer/target pairs)
MARGIN = 6.0
#: variance of a whitened residual relative to the weighting model (the margin's standard deviation)
_SPREAD = 3.0


def optimum_residual(sums: FormSum, gauge: tuple, value=None, drop: frozenset = frozenset(),
                     warm: JointSolution | None = None) -> float:
    """Joint residual of the forms of ``sums`` not in ``drop`` at their own optimum (forms not tied to the
    gauge left out; 0 when every form is dropped). ``warm``: a solution to start the solve from."""
    if len(drop) >= len(sums):
        return 0.0
    return sums.residual(sums.solve(gauge, value, drop, warm=warm).poses, drop)


def data_of(problems: Sequence[LocalProblem], member: Hashable, kind: str) -> list[int]:
    """Indices of the forms of ``problems`` that hold ``member``'s data of class ``kind`` (:data:`CLASSES`)."""
    out = []
    for i, prob in enumerate(problems):
        owners = [k[0] for k in prob.keys]
        pair = len(set(owners)) > 1
        if kind == "detections" and pair and owners[0] == member:
            out.append(i)
        elif kind == "odometry" and not pair and owners[0] == member:
            out.append(i)
        elif kind == "layout" and pair and owners[0] != member and member in owners:
            out.append(i)
    return out


def class_excess(problems: Sequence[LocalProblem], gauge: tuple, value=None, *, members=None,
                 min_count: int = MIN_COUNT) -> dict:
    r"""Per ``(member, class)`` with data, the excess residual per measurement :math:`e_h` of the module docstring.

    Parameters
    ----------
    problems : sequence of LocalProblem
        The window's forms over ``(member, step)`` keys, with their measurement counts.
    gauge : tuple
        The gauge key ``(reference, step)``.
    value : (R, p), optional
        The gauge's value.
    members : iterable, optional
        The members to test (default: every member but the gauge's).
    min_count : int
        Odometry classes with fewer scalar measurements are not tested.

    Returns
    -------
    dict
        ``(member, class)`` -> ``e_h`` (float); odometry classes with fewer than ``min_count`` measurements,
        and classes whose removal leaves the rest untied, are left out.
    """
    return _class_excess(FormSum(problems), gauge, value, frozenset(), members=members, min_count=min_count)


def _class_excess(sums: FormSum, gauge: tuple, value, drop: frozenset, *, members=None,
                  min_count: int = MIN_COUNT, above: float | None = None) -> dict:
    r""":func:`class_excess` of the forms of ``sums`` not in ``drop``; ``above``: only the classes whose excess may
    exceed it are solved again, the others are left out. The rest's residual is never negative, so
    :math:`e_h \le T(\text{all}) / m_h`: a class with :math:`T(\text{all}) \le` ``above`` :math:`m_h` cannot exceed
    ``above``. How many classes that spares depends on the window's total residual: of the classes of the
    windows the agents of ``multi`` rings screen (seeds 1-3), 31-63 % on 5-rings, 0-37 % on 8-rings, none on
    12-rings. The verdicts are the same (612 windows of honest and lying rings of 4-8 compared)."""
    problems = sums.problems
    whole = sums.solve(gauge, value, drop)
    total = sums.residual(whole.poses, drop)
    if members is None:
        members = sorted({k[0] for i, prob in enumerate(problems) if i not in drop for k in prob.keys} - {gauge[0]},
                         key=repr)
    out = {}
    for member in members:
        for kind in CLASSES:
            idx = frozenset(data_of(problems, member, kind)) - drop
            m = sum(int(problems[i].count) for i in idx)
            if not idx or m < (max(min_count, 1) if kind == "odometry" else 1):
                continue
            if above is not None and total <= above * m:
                continue  # (its excess is at most total / m: within bounds without a solve)
            try:  # (started from the whole window's optimum: one or two Newton steps instead of a spectral start)
                left = optimum_residual(sums, gauge, value, drop | idx, warm=whole)
            except np.linalg.LinAlgError:  # the rest does not tie its variables: no verdict on this class
                continue
            out[(member, kind)] = max(total - left, 0.0) / m
    return out


@dataclass(frozen=True)
class Attribution:
    r"""What :func:`attribute` found.

    Attributes
    ----------
    liar : hashable or None
        The member named (its data of the classes ``kinds`` contradict the others').
    kinds : tuple
        Those classes (each of them, removed, explains the window: a view shifted by a translation is
        explained by the liar's views or by the others' views of it alike).
    suspects : tuple
        When several members' classes each explain the inconsistency: those members.
    excess : dict
        ``(member, class)`` -> :math:`e_h` on all the forms, for the classes that could exceed the threshold
        (a class whose :math:`T(\text{all}) / m_h` is within it is not solved again: its excess is too).
    """

    liar: Hashable | None
    kinds: tuple
    suspects: tuple
    excess: dict


def attribute(problems: Sequence[LocalProblem] | FormSum, gauge: tuple, value=None, *,
              threshold: float = THRESHOLD) -> Attribution:
    """Name the member whose data of one class the others contradict (module docstring).

    ``problems``: the window's forms, or a :class:`decentral.admm.form_sum.FormSum` of them.

    Every class above ``threshold`` is a candidate; a candidate *explains* the window when, its forms
    removed, no class of the rest is above ``threshold``. One member among the explaining candidates:
    it is named (with its explaining classes); several: suspects;
    none (two liars, or a lie the rest cannot place): the members of the candidates are suspects.
    The gauge's member is never a candidate.

    Examples
    --------
    >>> from decentral.admm import quadratic_form
    >>> rng = np.random.default_rng(0)
    >>> at = {"A": (0.0, 0.0), "B": (3.0, 0.5), "C": (0.5, 3.0), "D": (-2.5, 1.0)}
    >>> q = np.array([[0.0, 0, 0], [0.6, 0, 0], [0.0, 0.4, 0]])
    >>> def seen(o, a, lie=0.0):  # o sees a's three nodes (1 cm noise); a liar's views are off by `lie` m
    ...     t = q + [*np.subtract(at[a], at[o]), 0.0] + 0.01 * rng.standard_normal((3, 3)) + [lie, 0, 0]
    ...     return quadratic_form([(o, 0), (a, 0)], visual=(np.zeros(3, int), np.ones(3, int), q, t,
    ...                                                     np.full(3, 1e4)))
    >>> attribute([seen(o, a) for o in at for a in at if o != a], ("A", 0)).liar is None
    True
    >>> found = attribute([seen(o, a, 0.1 if o == "C" else 0.0) for o in at for a in at if o != a], ("A", 0))
    >>> found.liar, "detections" in found.kinds
    ('C', True)
    """
    sums = problems if isinstance(problems, FormSum) else FormSum(problems)
    problems = sums.problems
    excess = _class_excess(sums, gauge, value, frozenset(), above=threshold)
    candidates = sorted((h for h, e in excess.items() if e > threshold), key=lambda h: -excess[h])
    if not candidates:
        return Attribution(None, (), (), excess)
    explaining, left = [], {}
    for member, kind in candidates:
        idx = frozenset(data_of(problems, member, kind))
        try:
            after = _class_excess(sums, gauge, value, idx, above=threshold)
            left[(member, kind)] = (optimum_residual(sums, gauge, value, idx),
                                    sum(int(problems[i].count) for i in idx),
                                    sum(int(p.count) for i, p in enumerate(problems) if i not in idx))
        except np.linalg.LinAlgError:
            continue
        if all(e <= threshold for e in after.values()):
            explaining.append((member, kind))
    members = sorted({m for m, _ in explaining}, key=repr)
    if len(members) > 1:
        members = _clearest(explaining, left)
    if len(members) == 1:
        return Attribution(members[0], tuple(k for m, k in explaining if m == members[0]), (), excess)
    suspects = members or sorted({m for m, _ in candidates}, key=repr)
    return Attribution(None, (), tuple(suspects), excess)


def _clearest(explaining: list, left: dict) -> list:
    r"""The members among several explanations, or the one whose explanation leaves clearly less residual.

    Removing class :math:`h` leaves :math:`T_h` on the rest; the removed measurements :math:`m_h` would
    have added about :math:`c\, m_h` had they been honest (:math:`c`: the best explanation's rest, per
    measurement), so :math:`A_h = T_h + c\, m_h` compares explanations that remove different amounts of
    data. A layout stretched under two observers, one of which sees it much better: removing the
    better observer's views leaves the other observer's (inconsistent) views of the liar, removing the
    liar's layout leaves nothing inconsistent, so the liar's :math:`A` is lower by many standard
    deviations (:math:`\sqrt{2 \cdot 3\,(m_h + m_{h'})}`); when the observer lies instead, the two
    explanations leave the same residual and both members stay suspects.
    """
    best = min(explaining, key=lambda h: left[h][0] / max(left[h][2], 1))
    c = left[best][0] / max(left[best][2], 1)
    score = {h: left[h][0] + c * left[h][1] for h in explaining}
    best = min(explaining, key=lambda h: score[h])
    others = [h for h in explaining if h[0] != best[0]]
    if all(score[h] - score[best] > MARGIN * np.sqrt(2 * _SPREAD * (left[h][1] + left[best][1])) for h in others):
        return [best[0]]
    return sorted({m for m, _ in explaining}, key=repr)
