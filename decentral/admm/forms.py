"""The quadratic cost forms ADMM works on: :class:`LocalProblem` and :func:`quadratic_form` (Liu et al. 2024 eq. (4), (7))."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from decentral.geometry import rot2

__all__ = ["LocalProblem", "Pose2", "quadratic_form"]

#: a planar pose value: (2, 2) rotation and (3,) position
Pose2 = tuple[np.ndarray, np.ndarray]



@dataclass(frozen=True)
class LocalProblem:
    """A quadratic form over ``n`` pose variables, the convention of :class:`decentral.window.WindowProblem`.

    Attributes
    ----------
    keys : tuple
        One hashable key per variable (``(assembly, step)``).
    M : ndarray, shape (3n, 3n)
        xy form over ``[P_xy | R2_1 .. R2_n]``.
    b_z : ndarray, shape (n,)
        z normal equations right-hand side (``cost_z = p_z^T M_pp p_z - 2 b_z^T p_z + c_z``).
    c_z : float
        Constant of the z cost.
    count : int
        Scalar measurements the form sums (3 per detection, 4 per odometry link: translation and yaw; 0
        when unknown): the degrees of freedom of its information-weighted cost
        (:func:`decentral.consistency.screen_members`).
    """

    keys: tuple
    M: np.ndarray
    b_z: np.ndarray
    c_z: float
    count: int = 0

    def __post_init__(self) -> None:
        for array in (self.M, self.b_z):
            if isinstance(array, np.ndarray):
                array.setflags(write=False)  # a form is a value: nothing writes into it once made

    def __deepcopy__(self, memo) -> "LocalProblem":
        """A value (frozen, its arrays read-only) is its own copy: an agent's fork (:meth:`agents.assembly.
        AssemblyAgent.fork`) shares its window's forms instead of copying every array."""
        return self

    @property
    def n(self) -> int:
        return len(self.keys)

    def cost(self, theta: np.ndarray, position: np.ndarray) -> float:
        """Joint cost at yaws ``theta`` (n,) and positions (n, 3)."""
        n = self.n
        X = np.hstack([position[:, :2].T, rot2(theta).transpose(1, 0, 2).reshape(2, 2 * n)])
        pz = position[:, 2]
        return float(np.trace(X @ self.M @ X.T) + pz @ self.M[:n, :n] @ pz - 2 * self.b_z @ pz + self.c_z)


def quadratic_form(keys, visual=None, odometry=None) -> LocalProblem:
    """Sum of weighted factor outer products over ``keys`` (Liu et al. 2024 eq. (5), (8), (11)).

    Parameters
    ----------
    keys : sequence
        Variable keys, ``n`` of them.
    visual : tuple of arrays, optional
        ``(io, ia, q, t, w)``: observer and target variable indices (d,), node centre in the target
        root frame ``q`` (d, 3), measured centre in the observer root frame ``t`` (d, 3) (eq. (4)),
        weights (d,).
    odometry : tuple of arrays, optional
        ``(iv, iu, dp, dtheta, w_p, w_R)``: variable at the previous step and at the step (e,),
        translation (e, 3) in the previous root frame, yaw increment (e,), weights (e,), (e,).
    """
    keys = tuple(keys)
    n = len(keys)
    rows_C, rows_w, rows_s = [], [], []
    M = np.zeros((3 * n, 3 * n))
    if visual is not None and len(visual[0]):
        io, ia, q, t, w = (np.asarray(a) for a in visual)
        C = np.zeros((len(io), 3 * n))
        r = np.arange(len(io))
        # Liu et al. 2024 eq. (4): e = R_a q + p_a - p_o - R_o t
        np.add.at(C, (r, ia), 1.0)
        np.add.at(C, (r, io), -1.0)
        np.add.at(C, (r, n + 2 * ia), q[:, 0])
        np.add.at(C, (r, n + 2 * ia + 1), q[:, 1])
        np.add.at(C, (r, n + 2 * io), -t[:, 0])
        np.add.at(C, (r, n + 2 * io + 1), -t[:, 1])
        rows_C.append(C), rows_w.append(np.asarray(w, float)), rows_s.append(q[:, 2] - t[:, 2])
    if odometry is not None and len(odometry[0]):
        iv, iu, dp, dth, w_p, w_R = (np.asarray(a) for a in odometry)
        C = np.zeros((len(iv), 3 * n))
        r = np.arange(len(iv))
        # Liu et al. 2024 eq. (7), position: e = p_u - p_v - R_v dp
        np.add.at(C, (r, iu), 1.0)
        np.add.at(C, (r, iv), -1.0)
        np.add.at(C, (r, n + 2 * iv), -dp[:, 0])
        np.add.at(C, (r, n + 2 * iv + 1), -dp[:, 1])
        rows_C.append(C), rows_w.append(np.asarray(w_p, float)), rows_s.append(-dp[:, 2])
        # Liu et al. 2024 eq. (7), rotation: ||R_u - R_v R̂||_F^2
        B = M[n:, n:].reshape(n, 2, n, 2)  # a view into M
        Rh = rot2(np.asarray(dth, float))
        for j in range(len(iv)):
            B[iu[j], :, iu[j], :] += w_R[j] * np.eye(2)
            B[iv[j], :, iv[j], :] += w_R[j] * np.eye(2)
            B[iu[j], :, iv[j], :] -= w_R[j] * Rh[j].T
            B[iv[j], :, iu[j], :] -= w_R[j] * Rh[j]
    if rows_C:
        C = np.vstack(rows_C)
        w = np.concatenate(rows_w)
        s = np.concatenate(rows_s)
        M += C.T @ (w[:, None] * C)
        Cp = C[:, :n]
        b_z = -Cp.T @ (w * s)
        c_z = float(np.sum(w * s * s))
    else:
        b_z, c_z = np.zeros(n), 0.0
    count = 3 * (len(visual[0]) if visual is not None else 0) + 4 * (len(odometry[0]) if odometry is not None else 0)
    return LocalProblem(keys, M, b_z, c_z, count)
