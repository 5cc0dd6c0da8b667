"""The ``"pcg"`` refiner: preconditioned nonlinear conjugate gradient, the refiner of Funiak et al. 2008 §VI-B/E."""

from __future__ import annotations

import numpy as np

from decentral.ensemble.problem import EnsembleProblem
from decentral.ensemble.refiners.base import RefineConfig, RefineResult, in_radii, no_observations
from decentral.ensemble.rotation import angle_to_matrix, so3_exp

__all__ = ["refine_pcg"]


def refine_pcg(problem: EnsembleProblem, position: np.ndarray, rotation: np.ndarray,
                config: RefineConfig) -> RefineResult:
    """Preconditioned nonlinear conjugate gradient on eq. 2 (the refiner of Funiak et al. 2008 §VI-B/E).

    Every iteration costs a fixed number of passes over the observations (gradient, one
    Jacobian-vector product, one or a few cost evaluations): no factorization, so information
    travels about one contact per iteration, which is what makes errors piled up far from where
    they are corrected slow to undo (Funiak et al. 2008 Fig. 3c). Positions move freely; orientations move
    by a right increment ``R exp([w]x)`` (an angle in 2D). The preconditioner is the block
    diagonal of the Gauss-Newton matrix (deg/4 per centre, sum |z|^2 per planar angle, sum
    (|z|^2 I - z z^T) per 3D increment); directions follow Polak-Ribiere+, the step is the
    Gauss-Newton minimizer along the direction, halved until the cost decreases (Armijo).
    """
    n, d, s = problem.n, problem.dim, problem.radius
    i, j = problem.i, problem.j
    z, x, R = in_radii(problem, position, rotation)
    if i.size == 0:
        return no_observations(x, R, s)
    p = 1 if d == 2 else 3
    deg = np.bincount(i, minlength=n) + np.bincount(j, minlength=n)
    px = 1.0 / np.maximum(deg / 4.0, 1e-12)
    zz = np.einsum("ea,ea->e", z, z)
    if d == 2:
        pr = 1.0 / np.maximum(np.bincount(i, zz, n), 1e-12)
    else:
        B = np.zeros((n, 3, 3))
        for a in range(3):
            for b in range(3):
                B[:, a, b] = np.bincount(i, (zz if a == b else 0.0) - z[:, a] * z[:, b], n)
        B += (1e-6 * np.trace(B, axis1=1, axis2=2)[:, None, None] + 1e-12) * np.eye(3)
        pr = np.linalg.inv(B)

    def rot_apply(Rm):
        return np.einsum("eab,eb->ea", Rm[i], z)

    def cost_grad(xc, Rm):
        rz = rot_apply(Rm)
        r = rz - 0.5 * (xc[j] - xc[i])
        gx = np.empty((n, d))
        for a in range(d):
            gx[:, a] = 0.5 * (np.bincount(i, r[:, a], n) - np.bincount(j, r[:, a], n))
        if d == 2:
            # d(R(theta) z)/d theta = J R z with J the 90-degree rotation
            gr = np.bincount(i, rz[:, 0] * r[:, 1] - rz[:, 1] * r[:, 0], n)[:, None]
        else:
            # d(R exp([w]x) z)/dw = -R [z]x, so the gradient is sum_e z x (R^T r_e)
            rl = np.einsum("eba,eb->ea", Rm[i], r)
            cz = np.cross(z, rl)
            gr = np.stack([np.bincount(i, cz[:, a], n) for a in range(3)], 1)
        return 0.5 * float(np.einsum("ea,ea->", r, r)), gx, gr, rz

    def precondition(gx, gr):
        hx = gx * px[:, None]
        hr = gr * pr[:, None] if d == 2 else np.einsum("nab,nb->na", pr, gr)
        return hx, hr

    def norm(gx, gr):
        if config.gnorm == "l2":
            return float(np.sqrt(np.einsum("na,na->", gx, gx) + np.einsum("na,na->", gr, gr)))
        return float(np.abs(gx).max())

    def retract(xc, Rm, dx, dr, alpha):
        if d == 2:
            return xc + alpha * dx, Rm @ angle_to_matrix(alpha * dr[:, 0])
        return xc + alpha * dx, Rm @ so3_exp(alpha * dr)

    E, gx, gr, rz = cost_grad(x, R)
    gnorm = norm(gx, gr)
    hx, hr = precondition(gx, gr)
    dx, dr = -hx, -hr
    gh = float(np.einsum("na,na->", gx, hx) + np.einsum("na,na->", gr, hr))
    it = 0
    status = "max_iter"
    while it < config.max_iter:
        if gnorm <= config.gtol or E <= 1e-30:
            status = "converged"
            break
        it += 1
        slope = float(np.einsum("na,na->", gx, dx) + np.einsum("na,na->", gr, dr))
        if not slope < 0:  # not a descent direction: restart from the preconditioned gradient
            dx, dr = -hx, -hr
            slope = -gh
        # Gauss-Newton step along the direction: alpha = -g.d / |J d|^2
        if d == 2:
            jr = dr[i, 0][:, None] * np.stack([-rz[:, 1], rz[:, 0]], 1)
        else:
            jr = np.einsum("eab,eb->ea", R[i], np.cross(dr[i], z))
        jd = jr + 0.5 * (dx[i] - dx[j])
        curv = float(np.einsum("ea,ea->", jd, jd))
        alpha = -slope / curv if curv > 0 else 1.0
        accepted = False
        for _ in range(30):
            xn, Rn = retract(x, R, dx, dr, alpha)
            En, gxn, grn, rzn = cost_grad(xn, Rn)
            if En <= E + 1e-4 * alpha * slope:
                accepted = True
                break
            alpha *= 0.5
        if not accepted:
            status = "stalled"
            break
        decrease = (E - En) / max(E, 1e-300)
        hxn, hrn = precondition(gxn, grn)
        ghn = float(np.einsum("na,na->", gxn, hxn) + np.einsum("na,na->", grn, hrn))
        # Polak-Ribiere+: beta = max(0, g_new . (h_new - h_old) / g_old . h_old)
        beta = max(0.0, (ghn - float(np.einsum("na,na->", gxn, hx) + np.einsum("na,na->", grn, hr))) / max(gh, 1e-300))
        dx, dr = -hxn + beta * dx, -hrn + beta * dr
        x, R, E, gx, gr, rz, hx, hr, gh = xn, Rn, En, gxn, grn, rzn, hxn, hrn, ghn
        gnorm = norm(gx, gr)
        if gnorm <= config.gtol or E <= 1e-30 or 0 <= decrease < config.ftol:
            status = "converged"
            break
    return RefineResult(x * s, R, E * s * s, norm(gx, gr), it, status)
