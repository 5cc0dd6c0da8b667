"""The sliding-window problem: variables, connectivity and the quadratic form (seed 000 eq. (9)-(14)).

A window covers ``K`` consecutive steps (``K = 1`` is a per-frame fit). Its variables are the root
frames ``(assembly, step)`` of every assembly that takes part in a visual factor inside the window,
plus the reference; only the connected component (through visual and odometry factors) that holds
the reference at the window's last step is kept, since nothing else can be placed relative to it.

Ordering of the quadratic form: ``x = [p_1 .. p_m | R2_1 .. R2_m]`` with positions first (one
column per variable, shared by x, y) then the two columns of each rotation's free part, so that

.. math:: \\text{cost}_{xy} = \\operatorname{tr}(X M X^T), \\quad X = [P_{xy}, \\underline{\\mathfrak{R}}] \\in \\mathbb{R}^{2 \\times 3m}

is seed 000 eq. (11)/(13) after the permutation ``T`` of eq. (13), restricted to the free parts
(eq. (15c) makes the z rows rotation-free). The z positions solve ``L p_z = b_z`` with ``L = M_pp``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from decentral.factors import StepMeasurements
from decentral.geometry import rot2

__all__ = ["WindowProblem", "build_window"]


@dataclass(frozen=True)
class WindowProblem:
    """One window's variables and quadratic form.

    Attributes
    ----------
    variables : tuple of (str, int)
        ``(assembly, step index)`` per variable, ``m`` of them.
    M : ndarray, shape (3m, 3m)
        xy quadratic form over ``[P_xy | R2 blocks]`` (eq. (14) blocks ``M_pp``, ``M_pR``, ``M_RR``).
    b_z : ndarray, shape (m,)
        Right-hand side of the z-position normal equations ``M_pp p_z = b_z``.
    c_z : float
        Constant of the z cost, so that its minimum is ``c_z - b_z^T p_z``.
    n_visual, n_odometry : int
        Factor counts.
    """

    variables: tuple[tuple[str, int], ...]
    M: np.ndarray
    b_z: np.ndarray
    c_z: float
    n_visual: int
    n_odometry: int

    @property
    def m(self) -> int:
        return len(self.variables)

    def index(self) -> dict[tuple[str, int], int]:
        return {key: i for i, key in enumerate(self.variables)}


def _window_links(measurements: list[StepMeasurements], steps: range, involved: list[str]):
    """Edges (pairs of variable keys) of the factor graph inside the window."""
    links = []
    for k in steps:
        vis = measurements[k].visual
        links.extend(((o, k), (a, k)) for o, a in zip(vis.observer, vis.target))
        if k != steps[0]:
            links.extend(((a, k - 1), (a, k)) for a in involved if a in measurements[k].odometry)
    return links


def build_window(measurements: list[StepMeasurements], steps: range, reference: str) -> WindowProblem | None:
    """Build the window over ``steps`` (indices into ``measurements``), anchored at ``reference``.

    Returns ``None`` when the reference takes part in no factor at the window's last step's component
    (nothing can be placed then).
    """
    last = steps[-1]
    involved = sorted({name for k in steps for name in measurements[k].visual.observer + measurements[k].visual.target})
    if reference not in involved:
        return None
    keys = [(a, k) for k in steps for a in involved]
    index = {key: i for i, key in enumerate(keys)}
    links = _window_links(measurements, steps, involved)
    if not links:
        return None
    src = [index[x] for x, _ in links]
    dst = [index[y] for _, y in links]
    graph = coo_matrix((np.ones(len(src)), (src, dst)), shape=(len(keys), len(keys)))
    _, label = connected_components(graph, directed=False)
    keep_label = label[index[(reference, last)]]
    kept = [key for key in keys if label[index[key]] == keep_label]
    if len(kept) < 2:
        return None
    return _assemble(measurements, steps, involved, tuple(kept))


def _assemble(measurements, steps, involved, variables) -> WindowProblem:
    m = len(variables)
    index = {key: i for i, key in enumerate(variables)}
    rows_C, rows_w, rows_s = [], [], []
    n_vis = n_odo = 0
    M_rot = np.zeros((2 * m, 2 * m))
    for k in steps:
        vis = measurements[k].visual
        for i, (o, a) in enumerate(zip(vis.observer, vis.target)):
            if (o, k) not in index or (a, k) not in index:
                continue
            io, ia = index[(o, k)], index[(a, k)]
            c = np.zeros(3 * m)
            # seed 000 eq. (4): e = R_a q + p_a - p_o - R_o t
            c[ia] += 1.0
            c[io] -= 1.0
            c[m + 2 * ia : m + 2 * ia + 2] += vis.q[i, :2]
            c[m + 2 * io : m + 2 * io + 2] -= vis.t[i, :2]
            rows_C.append(c)
            rows_w.append(vis.weight[i])
            rows_s.append(vis.q[i, 2] - vis.t[i, 2])
            n_vis += 1
        if k == steps[0]:
            continue
        for a in involved:
            odo = measurements[k].odometry.get(a)
            if odo is None or (a, k - 1) not in index or (a, k) not in index:
                continue
            iv, iu = index[(a, k - 1)], index[(a, k)]
            c = np.zeros(3 * m)
            # seed 000 eq. (7), position: e = p_u - p_v - R_v dp
            c[iu] += 1.0
            c[iv] -= 1.0
            c[m + 2 * iv : m + 2 * iv + 2] -= odo.dp[:2]
            rows_C.append(c)
            rows_w.append(odo.weight_p)
            rows_s.append(-odo.dp[2])
            # seed 000 eq. (7), rotation: ||R_u - R_v R̂||_F^2 = tr(R C C^T R^T), C = [.., I (u), .., -R̂ (v), ..]
            Rh = rot2(odo.dtheta)
            su, sv = slice(2 * iu, 2 * iu + 2), slice(2 * iv, 2 * iv + 2)
            M_rot[su, su] += odo.weight_R * np.eye(2)
            M_rot[sv, sv] += odo.weight_R * np.eye(2)
            M_rot[su, sv] -= odo.weight_R * Rh.T
            M_rot[sv, su] -= odo.weight_R * Rh
            n_odo += 1
    C = np.array(rows_C)
    w = np.array(rows_w)
    s = np.array(rows_s)
    M = C.T @ (w[:, None] * C)  # eq. (11): sum of weighted outer products of residual coefficients
    M[m:, m:] += M_rot
    Cp = C[:, :m]
    b_z = -Cp.T @ (w * s)
    c_z = float(np.sum(w * s * s))
    return WindowProblem(variables, M, b_z, c_z, n_vis, n_odo)
