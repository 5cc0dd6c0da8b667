"""Funiak et al.'s observation model, likelihood and analytic gradients (eq. 1-3), 2D and 3D.

Each directed observation ``e = (i, j)`` penalizes the distance between module i's sensor and the
midpoint of the two centres,

.. math::

    r_e = R_i z_{ij} - \\tfrac12 (c_j - c_i), \\qquad
    -\\log p(\\mathbf z \\mid \\mathbf x) = \\tfrac12 \\sum_e \\lVert r_e \\rVert^2 + \\text{const},

so the maximum likelihood estimate (eq. 3) minimizes :func:`negative_log_likelihood`. Orientations
are angles (2D) or quaternions (w, x, y, z) normalized implicitly inside the model (3D, Funiak et al. 2008
§VI-D), so the gradient with respect to an unnormalized quaternion is exact.

References
----------
.. [1] S. Funiak et al., "Distributed localization of modular robot ensembles", RSS 2008.
"""

from __future__ import annotations

import numpy as np
from scipy import sparse

from decentral.ensemble.problem import EnsembleProblem
from decentral.ensemble.rotation import angle_to_matrix, project_to_rotation, quat_to_matrix

__all__ = [
    "residuals",
    "negative_log_likelihood",
    "gradient",
    "residuals_from_matrices",
    "fit_orientations",
    "positions_given_rotations",
]


def _rotation(problem: EnsembleProblem, orientation: np.ndarray) -> np.ndarray:
    orientation = np.asarray(orientation, dtype=float)
    return angle_to_matrix(orientation) if problem.dim == 2 else quat_to_matrix(orientation)


def residuals_from_matrices(problem: EnsembleProblem, position: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """Residuals r_e (E, dim) of every observation, orientations given as matrices (n, dim, dim).

    Funiak et al. 2008 eq. (1): r_e = R_i z_ij - (c_j - c_i) / 2.
    """
    i, j = problem.i, problem.j
    rz = np.einsum("eab,eb->ea", rotation[i], problem.z)
    return rz - 0.5 * (position[j] - position[i])


def residuals(problem: EnsembleProblem, position: np.ndarray, orientation: np.ndarray) -> np.ndarray:
    """Residuals r_e (E, dim) for positions (n, dim) and orientations (angles (n,) or quaternions (n, 4))."""
    return residuals_from_matrices(problem, np.asarray(position, float), _rotation(problem, orientation))


def negative_log_likelihood(problem: EnsembleProblem, position: np.ndarray, orientation: np.ndarray) -> float:
    """Negative log-likelihood 1/2 sum_e |r_e|^2 (Funiak et al. 2008 eq. 2, constant dropped), metres^2."""
    r = residuals(problem, position, orientation)
    return 0.5 * float(np.einsum("ea,ea->", r, r))


def gradient(problem: EnsembleProblem, position: np.ndarray, orientation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Analytic gradient of :func:`negative_log_likelihood`.

    Parameters
    ----------
    problem : EnsembleProblem
    position : ndarray, shape (n, dim)
        Module centres in the global frame.
    orientation : ndarray, shape (n,) or (n, 4)
        Angles (2D) or quaternions (w, x, y, z) (3D; need not be unit: normalized implicitly).

    Returns
    -------
    grad_position : ndarray, shape (n, dim)
    grad_orientation : ndarray, shape (n,) or (n, 4)

    Notes
    -----
    The gradient is a sum of per-observation terms, each touching only the two modules of the
    observation, so module i can compute its own share from its neighbours' poses (Funiak et al. 2008 §V-A).
    """
    position = np.asarray(position, dtype=float)
    orientation = np.asarray(orientation, dtype=float)
    n, d = problem.n, problem.dim
    i, j, z = problem.i, problem.j, problem.z
    R = _rotation(problem, orientation)
    r = residuals_from_matrices(problem, position, R)
    g_pos = np.zeros((n, d))
    # d r_e / d c_i = +I/2, d r_e / d c_j = -I/2
    for a in range(d):
        g_pos[:, a] = 0.5 * (np.bincount(i, r[:, a], n) - np.bincount(j, r[:, a], n))
    if d == 2:
        rz = np.einsum("eab,eb->ea", R[i], z)
        # d(R(theta) z)/d theta = J R z with J the 90-degree rotation
        drz = np.stack([-rz[:, 1], rz[:, 0]], 1)
        g_ori = np.bincount(i, np.einsum("ea,ea->e", r, drz), n)
        return g_pos, g_ori
    q = orientation[i]
    w, v = q[:, 0], q[:, 1:]
    nq2 = np.einsum("ea,ea->e", q, q)
    vz = np.einsum("ea,ea->e", v, z)
    ve = np.einsum("ea,ea->e", v, r)
    ze = np.einsum("ea,ea->e", z, r)
    # g(q) = (w^2 - |v|^2) z + 2 (v.z) v + 2 w (v x z) = |q|^2 R(q) z; R(q) z = g / |q|^2
    g = (w * w - np.einsum("ea,ea->e", v, v))[:, None] * z + 2 * vz[:, None] * v + 2 * w[:, None] * np.cross(v, z)
    ge = np.einsum("ea,ea->e", g, r)
    dw = 2 * w * ze + 2 * np.einsum("ea,ea->e", np.cross(v, z), r)
    dv = -2 * ze[:, None] * v + 2 * vz[:, None] * r + 2 * ve[:, None] * z - 2 * w[:, None] * np.cross(r, z)
    per_edge = np.concatenate([dw[:, None], dv], 1) / nq2[:, None] - 2 * ge[:, None] * q / (nq2**2)[:, None]
    g_ori = np.stack([np.bincount(i, per_edge[:, a], n) for a in range(4)], 1)
    return g_pos, g_ori


def fit_orientations(problem: EnsembleProblem, position: np.ndarray) -> np.ndarray:
    """Best orientation (n, dim, dim) of every module given all centres, in closed form.

    For fixed centres the likelihood separates over modules: R_i = argmin sum_j |R z_ij - d_ij|^2
    with d_ij = (c_j - c_i)/2, a Kabsch problem solved per module (vectorized SVD). Modules without
    observations get the identity.
    """
    n, d = problem.n, problem.dim
    dvec = 0.5 * (position[problem.j] - position[problem.i])
    M = np.zeros((n, d, d))
    np.add.at(M, problem.i, dvec[:, :, None] * problem.z[:, None, :])
    lonely = np.bincount(problem.i, minlength=n) == 0
    M[lonely] = np.eye(d)
    return project_to_rotation(M)


def positions_given_rotations(problem: EnsembleProblem, rotation: np.ndarray, *, anchor: int = 0) -> np.ndarray:
    """Maximum-likelihood centres (n, dim) for fixed orientations: one sparse Laplacian solve.

    For fixed rotations the negative log-likelihood is a linear least-squares problem in the centres
    whose normal matrix is the graph Laplacian; module ``anchor`` is held at the origin (the
    problem is invariant to translation). Assumes a connected contact graph. This is the cheapest
    global computation on the graph, used as the floor of the scaling benchmark.
    """
    from scipy.sparse.linalg import splu

    n, d = problem.n, problem.dim
    i, j = problem.i, problem.j
    # residual r_e = R_i z_e - (c_j - c_i)/2  ->  c_j - c_i ~ 2 R_i z_e
    t = 2.0 * np.einsum("eab,eb->ea", rotation[i], problem.z)
    L = sparse.csr_matrix((np.ones(i.size), (i, j)), shape=(n, n))
    L = sparse.diags(np.asarray(L.sum(1)).ravel() + np.asarray(L.sum(0)).ravel()) - L - L.T
    b = np.zeros((n, d))
    for a in range(d):
        b[:, a] = np.bincount(j, t[:, a], n) - np.bincount(i, t[:, a], n)
    keep = np.arange(n) != anchor
    Lr = L.tocsc()[keep][:, keep].tocsc()
    c = np.zeros((n, d))
    if n > 1:
        c[keep] = splu(Lr, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                       options={"SymmetricMode": True}).solve(b[keep])
    return c
