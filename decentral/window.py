"""The sliding-window problem: variables, connectivity and the quadratic form (Liu et al. 2024 eq. (9)-(14)).

A window covers ``K`` consecutive steps (``K = 1`` is a per-frame fit). Its variables are the root
frames ``(assembly, step)`` of every assembly that takes part in a visual factor inside the window,
plus the reference; only the connected component (through visual and odometry factors) that holds
the reference at the window's last step is kept, since nothing else can be placed relative to it.

Ordering of the quadratic form: ``x = [p_1 .. p_m | R2_1 .. R2_m]`` with positions first (one
column per variable, shared by x, y) then the two columns of each rotation's free part, so that

.. math:: \\text{cost}_{xy} = \\operatorname{tr}(X M X^T), \\quad X = [P_{xy}, \\underline{\\mathfrak{R}}] \\in \\mathbb{R}^{2 \\times 3m}

is Liu et al. 2024 eq. (11)/(13) after the permutation ``T`` of eq. (13), restricted to the free parts
(eq. (15c) makes the z rows rotation-free). The z positions solve ``L p_z = b_z`` with ``L = M_pp``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

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


def _components(n: int, src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Connected-component label (n,) of an undirected graph given by edge arrays (union-find)."""
    parent = np.arange(n)

    def find(x: int) -> int:
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    for a, b in zip(src.tolist(), dst.tolist()):
        ra, rb = find(a), find(b)
        if ra != rb:
            parent[max(ra, rb)] = min(ra, rb)
    return np.array([find(x) for x in range(n)])


def _factor_rows(measurements: list[StepMeasurements], steps: range, involved: list[str]):
    """Every factor of the window as arrays: visual (step, observer, target, detection index) and
    odometry (step, assembly)."""
    vis = [(k, o, a, i) for k in steps for i, (o, a) in enumerate(zip(measurements[k].visual.observer,
                                                                        measurements[k].visual.target))]
    odo = [(k, a) for k in steps[1:] for a in involved if a in measurements[k].odometry]
    return vis, odo


def build_window(measurements: list[StepMeasurements], steps: range, reference: str) -> WindowProblem | None:
    """Build the window over ``steps`` (indices into ``measurements``), anchored at ``reference``.

    Returns ``None`` when the reference's root at the window's last step is tied to nothing.
    """
    last = steps[-1]
    involved = sorted({name for k in steps for name in measurements[k].visual.observer + measurements[k].visual.target})
    if reference not in involved:
        return None
    slot = {a: j for j, a in enumerate(involved)}
    n_a = len(involved)
    key = lambda a, k: (k - steps[0]) * n_a + slot[a]  # noqa: E731
    vis, odo = _factor_rows(measurements, steps, involved)
    src = np.array([key(o, k) for k, o, _, _ in vis] + [key(a, k - 1) for k, a in odo], dtype=int)
    dst = np.array([key(a, k) for k, _, a, _ in vis] + [key(a, k) for k, a in odo], dtype=int)
    label = _components(n_a * len(steps), src, dst)
    keep = label == label[key(reference, last)]
    if keep.sum() < 2:
        return None
    variables = tuple((involved[j % n_a], steps[0] + j // n_a) for j in np.flatnonzero(keep))
    return _assemble(measurements, variables, vis, odo)


def _assemble(measurements, variables, vis, odo) -> WindowProblem:
    """The quadratic form of the kept variables from the window's factor rows (vectorized)."""
    m = len(variables)
    index = {key: i for i, key in enumerate(variables)}
    vis = [(k, o, a, i) for k, o, a, i in vis if (o, k) in index]
    odo = [(k, a) for k, a in odo if (a, k) in index]
    n_v, n_o = len(vis), len(odo)
    C = np.zeros((n_v + n_o, 3 * m))
    w = np.empty(n_v + n_o)
    s = np.empty(n_v + n_o)
    if n_v:
        io = np.array([index[(o, k)] for k, o, _, _ in vis])
        ia = np.array([index[(a, k)] for k, _, a, _ in vis])
        q = np.array([measurements[k].visual.q[i] for k, _, _, i in vis])
        t = np.array([measurements[k].visual.t[i] for k, _, _, i in vis])
        w[:n_v] = [measurements[k].visual.weight[i] for k, _, _, i in vis]
        rows = np.arange(n_v)
        # Liu et al. 2024 eq. (4): e = R_a q + p_a - p_o - R_o t
        C[rows, ia] += 1.0
        C[rows, io] -= 1.0
        C[rows, m + 2 * ia] += q[:, 0]
        C[rows, m + 2 * ia + 1] += q[:, 1]
        C[rows, m + 2 * io] -= t[:, 0]
        C[rows, m + 2 * io + 1] -= t[:, 1]
        s[:n_v] = q[:, 2] - t[:, 2]
    M_rot = np.zeros((2 * m, 2 * m))
    if n_o:
        iv = np.array([index[(a, k - 1)] for k, a in odo])
        iu = np.array([index[(a, k)] for k, a in odo])
        meas = [measurements[k].odometry[a] for k, a in odo]
        dp = np.array([o.dp for o in meas])
        w[n_v:] = [o.weight_p for o in meas]
        rows = n_v + np.arange(n_o)
        # Liu et al. 2024 eq. (7), position: e = p_u - p_v - R_v dp
        C[rows, iu] += 1.0
        C[rows, iv] -= 1.0
        C[rows, m + 2 * iv] -= dp[:, 0]
        C[rows, m + 2 * iv + 1] -= dp[:, 1]
        s[n_v:] = -dp[:, 2]
        # Liu et al. 2024 eq. (7), rotation: ||R_u - R_v R̂||_F^2 = tr(R C C^T R^T), C = [.., I (u), .., -R̂ (v), ..]
        kappa = np.array([o.weight_R for o in meas])
        Rh = rot2(np.array([o.dtheta for o in meas]))
        B = M_rot.reshape(m, 2, m, 2)
        eye = np.eye(2)
        for j in range(n_o):
            B[iu[j], :, iu[j], :] += kappa[j] * eye
            B[iv[j], :, iv[j], :] += kappa[j] * eye
            B[iu[j], :, iv[j], :] -= kappa[j] * Rh[j].T
            B[iv[j], :, iu[j], :] -= kappa[j] * Rh[j]
    M = C.T @ (w[:, None] * C)  # eq. (11): sum of weighted outer products of residual coefficients
    M[m:, m:] += M_rot
    Cp = C[:, :m]
    b_z = -Cp.T @ (w * s)
    c_z = float(np.sum(w * s * s))
    return WindowProblem(variables, M, b_z, c_z, n_v, n_o)
