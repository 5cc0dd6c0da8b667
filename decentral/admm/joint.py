"""The joint solution of shared cost forms (:func:`solve_joint`): where every agent can start its ADMM."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from decentral.admm.forms import LocalProblem, Pose2
from decentral.estimator import placeable_yaws
from decentral.geometry import rot2, yaw_of
from decentral.relaxation import recover_positions, reduce_rotations, solve_low_rank

__all__ = ["JointSolution", "solve_joint", "solve_form"]


def _joint_form(problems: list[LocalProblem], fixed_key) -> tuple[list, dict, np.ndarray, np.ndarray]:
    """The summed window form over the variables connected to ``fixed_key``.

    Returns the keys (sorted), key -> index, ``M`` (3n, 3n) over ``[P_xy | R]`` and ``b_z`` (n,).
    """
    edges: dict = {}
    for prob in problems:
        for a in prob.keys:
            edges.setdefault(a, set()).update(prob.keys)
    comp, todo = {fixed_key}, [fixed_key]
    while todo:
        for b in edges.get(todo.pop(), ()):
            if b not in comp:
                comp.add(b)
                todo.append(b)
    keys = sorted(comp, key=repr)
    index = {k: i for i, k in enumerate(keys)}
    n = len(keys)
    M = np.zeros((3 * n, 3 * n))
    b_z = np.zeros(n)
    for prob in problems:
        if prob.keys[0] not in index:
            continue
        g = np.array([index[k] for k in prob.keys])
        gc = np.concatenate([g, np.stack([n + 2 * g, n + 2 * g + 1], 1).ravel()])
        m = prob.n
        lc = np.concatenate([np.arange(m), np.stack([m + 2 * np.arange(m), m + 2 * np.arange(m) + 1], 1).ravel()])
        M[np.ix_(gc, gc)] += prob.M[np.ix_(lc, lc)]
        b_z[g] += prob.b_z
    return keys, index, M, b_z


@dataclass(frozen=True)
class JointSolution:
    """The joint window of the shared forms, solved (:func:`solve_joint`).

    Attributes
    ----------
    poses : dict
        key -> ``Pose2`` for every variable connected to the gauge variable.
    index : dict
        key -> index into ``theta`` and the rows of ``Q``.
    Q : ndarray, shape (2m, 2m)
        The rotation-only cost after eliminating positions (Liu et al. 2024 eq. (14)); empty for one variable.
    theta : ndarray, shape (m,)
        The yaws at the optimum.
    """

    poses: dict
    index: dict
    Q: np.ndarray
    theta: np.ndarray

    def placeable(self, reference, max_yaw_std: float) -> frozenset:
        """Keys at ``reference``'s step that the centralized estimator would place relative to it.

        The same test as :func:`decentral.estimator.placeable_yaws` (the relative yaw is outside the
        null space of the yaw Hessian and its Laplace standard deviation is at most ``max_yaw_std``);
        nothing when ``reference`` is not tied to the gauge variable.
        """
        return self.placement(reference, max_yaw_std)[0]

    def placement(self, reference, max_yaw_std: float) -> tuple[frozenset, dict]:
        """:meth:`placeable` and the relative-yaw standard deviations (assembly -> rad) it tested."""
        if reference not in self.index or len(self.index) == 1:
            return frozenset(), {}
        return placeable_yaws(self.Q, self.theta, self.index, reference, max_yaw_std)


def solve_joint(problems: list[LocalProblem], fixed_key, fixed_value: Pose2 | None = None) -> JointSolution:
    r"""Minimize the sum of local problems over the variables tied to ``fixed_key`` (held fixed).

    The cold start of the ADMM: the pair forms of one step, shared by every agent, summed into the
    joint problem (their sum is the joint cost, as for :func:`decentral.window.build_window`),
    restricted to the connected component of the gauge variable, solved gauge-free like the
    centralized window (rotations eliminated per Liu et al. 2024 eq. (14), the certified low-rank solve,
    positions per eq. (18)) and moved rigidly so that the gauge variable takes its value (identity by
    default). Deterministic in its inputs, so agents that hold the same forms get bit-identical answers.

    Parameters
    ----------
    problems : list of LocalProblem
        The forms (any keys; a key shared by several forms is one variable).
    fixed_key : hashable
        The gauge variable.
    fixed_value : Pose2, optional
        Its value; the identity by default.

    Returns
    -------
    JointSolution
        Its ``poses``: key -> ``Pose2`` for every variable connected to ``fixed_key`` (only
        ``fixed_key`` when nothing is); and what the placement test needs.
    """
    keys, _, M, b_z = _joint_form(problems, fixed_key)
    return solve_form(keys, M, b_z, fixed_key, fixed_value)


def solve_form(keys: list, M: np.ndarray, b_z: np.ndarray, fixed_key, fixed_value: Pose2 | None = None,
               theta0: np.ndarray | None = None) -> JointSolution:
    """:func:`solve_joint` of a form already summed: ``M`` (3n, 3n) over ``[P_xy | R]`` and ``b_z`` (n,) over
    ``keys`` (n, the gauge variable ``fixed_key`` among them, every one tied to it); ``theta0`` (n,): yaws to
    start the rotation solve from (:func:`decentral.relaxation.solve_low_rank`)."""
    fixed_value = fixed_value or (np.eye(2), np.zeros(3))
    index = {k: i for i, k in enumerate(keys)}
    if len(keys) == 1:
        return JointSolution({fixed_key: fixed_value}, index, np.zeros((0, 0)), np.zeros(1))
    n = len(keys)
    # gauge-free, as the centralized window (Liu et al. 2024 eq. (14)-(18)), then moved onto the fixed value
    Q = reduce_rotations(M, n)
    res = solve_low_rank(Q, theta0)
    position = recover_positions(M, res.theta, b_z)
    f = index[fixed_key]
    d = float(yaw_of(fixed_value[0])) - res.theta[f]
    Rd = rot2(d)
    theta = res.theta + d
    p_fix = np.asarray(fixed_value[1], float)
    position[:, :2] = (position[:, :2] - position[f, :2]) @ Rd.T + p_fix[:2]
    position[:, 2] += p_fix[2] - position[f, 2]
    R = rot2(theta)
    return JointSolution({k: (R[i], position[i]) for i, k in enumerate(keys)}, index, Q, theta)
