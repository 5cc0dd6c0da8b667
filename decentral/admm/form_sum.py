"""A window's forms summed once, re-summed without any of them in one vectorized pass.

The lie tests (:mod:`decentral.consistency`, :mod:`decentral.attribution`) solve a window again and
again with some of its forms left out (a member's, one class of a member's data) and evaluate every
form's cost at each answer: some 20 solves a window on an 8-ring. Summing the forms one by one
(:func:`decentral.admm.joint._joint_form`) and evaluating each form's cost in turn took four fifths
of that time. :class:`FormSum` lays every form's entries out once over the union of the keys; the
sum of any subset is then one ``bincount`` over the kept entries, in the same order as summing form
by form (so a subset's sum is bit-identical to the direct one), and the costs of all the forms at
one set of poses are one gather.

Examples
--------
>>> import numpy as np
>>> from decentral.admm import quadratic_form, solve_joint
>>> q = np.array([[0.0, 0, 0], [0.6, 0, 0], [0.0, 0.4, 0]])
>>> def seen(o, a, t):  # o sees a's three nodes with a's root at t in o's frame
...     return quadratic_form([(o, 0), (a, 0)], visual=(np.zeros(3, int), np.ones(3, int), q, q + t,
...                                                     np.full(3, 1e4)))
>>> forms = [seen("A", "B", [1.0, 0, 0]), seen("B", "C", [0.0, 1, 0]), seen("A", "C", [1.0, 1.1, 0])]
>>> sums = FormSum(forms)
>>> rest = sums.solve(("A", 0), drop={2})  # without A's view of C
>>> direct = solve_joint(forms[:2], ("A", 0))
>>> bool(np.allclose(rest.poses[("C", 0)][1], direct.poses[("C", 0)][1]))
True
>>> costs = sums.costs(rest.poses)  # the third form is the only one the answer leaves a residual in
>>> bool(np.allclose(costs, [0.0, 0.0, 300.0], atol=1e-6))  # 3 nodes 0.1 m off, weight 1e4
True
"""

from __future__ import annotations

from typing import Collection, Sequence

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from decentral.admm.forms import LocalProblem, Pose2
from decentral.admm.joint import JointSolution, solve_form

__all__ = ["FormSum"]


class FormSum:
    """The forms ``problems`` (``P`` of them, over ``N`` distinct keys) laid out for summing any subset.

    The global layout is :func:`decentral.admm.solve_joint`'s: keys sorted by ``repr``, ``M`` (3N, 3N)
    over ``[P_xy (N) | R2_1 .. R2_N (2N)]``, ``b_z`` (N,).

    Parameters
    ----------
    problems : sequence of LocalProblem
        The window's forms; they are referred to by their position in this sequence.
    """

    def __init__(self, problems: Sequence[LocalProblem]):
        self.problems = list(problems)
        self.keys = sorted({k for prob in self.problems for k in prob.keys}, key=repr)
        self.index = {k: i for i, k in enumerate(self.keys)}
        n = len(self.keys)
        flat, vals, owner, b_at, b_vals, b_owner, first, other = [], [], [], [], [], [], [], []
        for i, prob in enumerate(self.problems):
            g = np.array([self.index[k] for k in prob.keys])
            m = prob.n
            gc = np.concatenate([g, np.stack([n + 2 * g, n + 2 * g + 1], 1).ravel()])
            lc = np.concatenate([np.arange(m), np.stack([m + 2 * np.arange(m), m + 2 * np.arange(m) + 1], 1).ravel()])
            flat.append((gc[:, None] * 3 * n + gc[None, :]).ravel())
            vals.append(np.asarray(prob.M, float)[np.ix_(lc, lc)].ravel())
            owner.append(np.full(9 * m * m, i))
            b_at.append(g)
            b_vals.append(np.asarray(prob.b_z, float))
            b_owner.append(np.full(m, i))
            first.append(np.full(m, g[0]))  # edges from the form's first key to each of its keys: what ties them
            other.append(g)
        empty = np.zeros(0, int)
        cat = lambda parts, dtype=int: np.concatenate(parts).astype(dtype) if parts else np.zeros(0, dtype)  # noqa: E731
        self._flat, self._vals, self._owner = cat(flat), cat(vals, float), cat(owner)
        self._b_at, self._b_vals, self._b_owner = cat(b_at), cat(b_vals, float), cat(b_owner)
        self._edges = (cat(first), cat(other))
        self._c = np.array([float(prob.c_z) for prob in self.problems])
        # entry of M at (row, col) and whether both lie in the position block (the z cost uses M_pp too)
        self._row, self._col = np.divmod(self._flat, 3 * n) if n else (empty, empty)
        self._pp = (self._row < n) & (self._col < n)

    def __len__(self) -> int:
        return len(self.problems)

    def _kept(self, drop: Collection[int]) -> np.ndarray:
        keep = np.ones(len(self.problems), bool)
        if len(drop):
            keep[np.fromiter(drop, int)] = False
        return keep

    def component(self, key, drop: Collection[int] = ()) -> np.ndarray:
        """Indices (into :attr:`keys`, ascending) of the keys tied to ``key`` by the forms not in ``drop``."""
        n = len(self.keys)
        keep = self._kept(drop)[self._b_owner]
        graph = coo_matrix((np.ones(int(keep.sum())), (self._edges[0][keep], self._edges[1][keep])), shape=(n, n))
        _, labels = connected_components(graph, directed=False)
        return np.flatnonzero(labels == labels[self.index[key]])

    def form(self, drop: Collection[int] = ()) -> tuple[np.ndarray, np.ndarray]:
        """``M`` (3N, 3N) and ``b_z`` (N,): the sum of every form not in ``drop``, form by form in order."""
        n = len(self.keys)
        keep = self._kept(drop)
        sel = keep[self._owner]
        M = np.bincount(self._flat[sel], weights=self._vals[sel], minlength=9 * n * n).reshape(3 * n, 3 * n)
        b_sel = keep[self._b_owner]
        b_z = np.bincount(self._b_at[b_sel], weights=self._b_vals[b_sel], minlength=n)
        return M, b_z

    def solve(self, fixed_key, fixed_value: Pose2 | None = None, drop: Collection[int] = (),
              warm: JointSolution | None = None) -> JointSolution:
        """:func:`decentral.admm.solve_joint` of the forms not in ``drop`` (same layout, same certified answer).

        ``warm``: a solution of nearby forms (the whole window's) whose yaws start the rotation solve; the
        spectral start is still tried when that one does not certify. Raises ``numpy.linalg.LinAlgError``
        where :func:`decentral.admm.solve_joint` does.
        """
        if fixed_key not in self.index:  # (no form holds the gauge: it alone, as solve_joint answers)
            return solve_form([fixed_key], np.zeros((3, 3)), np.zeros(1), fixed_key, fixed_value)
        n = len(self.keys)
        comp = self.component(fixed_key, drop)
        M, b_z = self.form(drop)
        cols = np.concatenate([comp, np.stack([n + 2 * comp, n + 2 * comp + 1], 1).ravel()])
        keys = [self.keys[i] for i in comp]
        theta0 = None
        if warm is not None and len(keys) > 1:
            theta0 = np.array([warm.theta[warm.index[k]] if k in warm.index else 0.0 for k in keys])
        return solve_form(keys, M[np.ix_(cols, cols)], b_z[comp], fixed_key, fixed_value, theta0=theta0)

    def residual(self, poses: dict, drop: Collection[int] = ()) -> float:
        """Summed cost of the forms not in ``drop`` at ``poses``, those over a key ``poses`` lacks left out
        (:func:`decentral.consistency.residual`)."""
        costs = self.costs(poses)
        costs[~self._kept(drop)] = np.nan
        return float(np.nansum(costs))

    def costs(self, poses: dict) -> np.ndarray:
        """Each form's cost (P,) at ``poses`` (key -> ``(R (2, 2), p (3,))``), as :meth:`LocalProblem.cost`;
        ``nan`` for a form over a key that ``poses`` lacks (it is not tied to that solution)."""
        n, P = len(self.keys), len(self.problems)
        X = np.zeros((2, 3 * n))
        pz = np.zeros(n)
        have = np.zeros(n, bool)
        for k, (R, p) in poses.items():
            i = self.index.get(k)
            if i is None:
                continue
            have[i] = True
            X[:, i] = np.asarray(p, float)[:2]
            X[:, n + 2 * i: n + 2 * i + 2] = np.asarray(R, float)
            pz[i] = float(p[2])
        # trace(X M X^T) + p_z^T M_pp p_z - 2 b_z^T p_z + c_z, entry by entry, summed per form
        xx = np.einsum("ij,ij->j", X[:, self._row], X[:, self._col])
        zz = np.where(self._pp, pz[np.minimum(self._row, n - 1)] * pz[np.minimum(self._col, n - 1)], 0.0)
        out = np.bincount(self._owner, weights=self._vals * (xx + zz), minlength=P)
        out -= 2 * np.bincount(self._b_owner, weights=self._b_vals * pz[self._b_at], minlength=P)
        out += self._c
        missing = np.bincount(self._b_owner, weights=~have[self._b_at], minlength=P)
        out[missing > 0] = np.nan
        return out
