"""The ``"lm"`` refiner: Levenberg-Marquardt on the full Jacobian (positions and orientation increments), one sparse LU per iteration."""

from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.sparse.linalg import splu

from decentral.ensemble.problem import EnsembleProblem
from decentral.ensemble.refiners.base import RefineConfig, RefineResult, gradient_norm, in_radii, no_observations
from decentral.ensemble.rotation import angle_to_matrix, skew, so3_exp

__all__ = ["refine_lm"]


def _residual(i, j, z, c, R):
    rz = np.einsum("eab,eb->ea", R[i], z)
    return rz, rz - 0.5 * (c[j] - c[i])


def _jacobian(n, d, i, j, z, R, rz):
    E = i.size
    p = 1 if d == 2 else 3
    rows_e = np.arange(E) * d
    rows, cols, vals = [], [], []
    for a in range(d):
        rows += [rows_e + a, rows_e + a]
        cols += [i * d + a, j * d + a]
        vals += [np.full(E, 0.5), np.full(E, -0.5)]
    if d == 2:
        drz = np.stack([-rz[:, 1], rz[:, 0]], 1)  # d(R(theta) z)/d theta = J R z
        for a in range(2):
            rows.append(rows_e + a)
            cols.append(n * d + i)
            vals.append(drz[:, a])
    else:
        # d(R exp([w]x) z)/dw at w = 0 is -R [z]x
        Jr = -np.einsum("eab,ebc->eac", R[i], skew(z))
        for a in range(3):
            for b in range(3):
                rows.append(rows_e + a)
                cols.append(n * d + 3 * i + b)
                vals.append(Jr[:, a, b])
    J = sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                          shape=(E * d, n * (d + p)))
    return J


def _retract(d, c, R, step, n):
    dc = step[: n * d].reshape(n, d)
    dr = step[n * d:]
    if d == 2:
        Rn = R @ angle_to_matrix(dr)
    else:
        Rn = R @ so3_exp(dr.reshape(n, 3))
    return c + dc, Rn


def refine_lm(problem: EnsembleProblem, position: np.ndarray, rotation: np.ndarray,
               config: RefineConfig) -> RefineResult:
    n, d, s = problem.n, problem.dim, problem.radius
    i, j = problem.i, problem.j
    z, c, R = in_radii(problem, position, rotation)
    if i.size == 0:
        return no_observations(c, R, s)
    rz, r = _residual(i, j, z, c, R)
    cost = 0.5 * float(np.einsum("ea,ea->", r, r))
    lam = config.damping
    it = 0
    status = "max_iter"
    gnorm = np.inf
    J = _jacobian(n, d, i, j, z, R, rz)
    g = J.T @ r.ravel()
    gnorm = gradient_norm(g, config.gnorm)
    while it < config.max_iter:
        if gnorm <= config.gtol or cost <= 1e-30:
            status = "converged"
            break
        H = (J.T @ J).tocsc()
        diag = H.diagonal()
        A = H + sparse.diags(lam * diag + 1e-12)
        it += 1
        try:
            step = splu(A.tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                        options={"SymmetricMode": True}).solve(-g)
        except RuntimeError:
            status = "stalled"
            break
        if not np.all(np.isfinite(step)):
            status = "stalled"
            break
        c_new, R_new = _retract(d, c, R, step, n)
        rz_new, r_new = _residual(i, j, z, c_new, R_new)
        cost_new = 0.5 * float(np.einsum("ea,ea->", r_new, r_new))
        if cost_new < cost:
            decrease = (cost - cost_new) / max(cost, 1e-300)
            c, R, rz, r, cost = c_new, R_new, rz_new, r_new, cost_new
            lam = max(lam / 10.0, 1e-12)
            J = _jacobian(n, d, i, j, z, R, rz)
            g = J.T @ r.ravel()
            gnorm = gradient_norm(g, config.gnorm)
            if decrease < config.ftol:
                status = "converged"
                break
        else:
            lam *= 10.0
            if lam > 1e8:
                status = "stalled"
                break
    else:
        if gnorm <= config.gtol:
            status = "converged"
    return RefineResult(c * s, R, cost * s * s, gnorm, it, status)
