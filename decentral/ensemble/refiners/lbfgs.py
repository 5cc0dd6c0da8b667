"""The ``"lbfgs"`` refiner: L-BFGS on the centres, orientations fitted in closed form, initial inverse Hessian 4 L^-1."""

from __future__ import annotations

import numpy as np

from decentral.ensemble.coarse import TwoLevelInverse, cluster_labels
from decentral.ensemble.problem import EnsembleProblem
from decentral.ensemble.refiners.base import (
    DecreaseTest,
    RefineConfig,
    RefineResult,
    block_setup,
    gradient_norm,
    in_radii,
    no_observations,
)

__all__ = ["refine_lbfgs"]


def refine_lbfgs(problem: EnsembleProblem, position: np.ndarray, rotation: np.ndarray,
                  config: RefineConfig, fixed: np.ndarray | None = None,
                  elimination: np.ndarray | None = None) -> RefineResult:
    """L-BFGS on the centres with the orientations fitted in closed form (variable projection).

    F(c) = min_R cost(c, R); by the envelope theorem its gradient is the position gradient at the
    fitted orientations. The initial inverse Hessian is 4 L^-1, the exact inverse of the position
    block (cost = (1/8) |B c - 2 R z|^2 for fixed R, B the incidence matrix, L = B^T B), applied
    with the factorized Laplacian; one module per component is held (translation gauge). With
    ``config.coarse_size`` > 0 (and at least twice that many modules) it is the two-level operator
    of :class:`~decentral.ensemble.coarse.TwoLevelInverse`, built once at the start.
    """
    s = problem.radius
    z, x, R0 = in_radii(problem, position, rotation)
    if problem.num_observations == 0:
        return no_observations(x, R0, s)
    lap, rots, _, fit, inc = block_setup(problem, z, R0, fixed, config.ordering, elimination)
    free = lap.free

    def reduced(c):  # F(c), its gradient (n, d) and the fitted orientations (held ones kept)
        half = inc.half(c)
        state = fit(half)
        r = rots.apply(state) - half
        g = inc.gradient(r)  # envelope theorem: the orientations are optimal
        g[~free] = 0.0
        # Funiak et al. 2008 eq. (3): negative log-likelihood 1/2 sum_e |R_i z_e - (c_j - c_i)/2|^2
        return 0.5 * float(np.einsum("ea,ea->", r, r)), g, state

    def fine(v):  # 4 L^-1 v on the free modules
        out = np.zeros_like(v)
        out[free] = 4.0 * lap.solve_reduced(v[free])
        return out

    E, g, state = reduced(x)  # the closed-form fit is never worse than the given orientations
    h0 = fine
    if config.coarse_size > 0 and problem.n >= 2 * config.coarse_size:
        turning = np.ones(problem.n, dtype=bool) if fixed is None else ~fixed
        h0 = TwoLevelInverse(problem.i, problem.j, inc.B, x, rots.apply(state),
                             cluster_labels(problem.adjacency(), config.coarse_size), free, turning, fine)
    levelled_off = DecreaseTest(config, E)
    S: list[np.ndarray] = []
    Y: list[np.ndarray] = []
    rho: list[float] = []
    it = 0
    status = "max_iter"
    gnorm = gradient_norm(g, config.gnorm)
    while it < config.max_iter:
        if gnorm <= config.gtol or E <= 1e-30:
            status = "converged"
            break
        it += 1
        # two-loop recursion: p = -H g
        q = g.copy()
        alphas = []
        for sk, yk, rk in zip(reversed(S), reversed(Y), reversed(rho)):
            a = rk * float(np.vdot(sk, q))
            alphas.append(a)
            q -= a * yk
        p = h0(q)
        for sk, yk, rk, a in zip(S, Y, rho, reversed(alphas)):
            p += (a - rk * float(np.vdot(yk, p))) * sk
        p = -p
        slope = float(np.vdot(g, p))
        if not slope < 0:  # the memory lost positive definiteness numerically: restart
            S, Y, rho = [], [], []
            p = -h0(g)
            slope = float(np.vdot(g, p))
            if not slope < 0:
                status = "stalled"
                break
        t = 1.0
        for _ in range(30):
            x_new = x + t * p
            E_new, g_new, state_new = reduced(x_new)
            if E_new <= E + 1e-4 * t * slope:
                break
            t *= 0.5
        else:
            status = "stalled"
            break
        sk, yk = x_new - x, g_new - g
        sy = float(np.vdot(sk, yk))
        if sy > 1e-12 * float(np.vdot(yk, yk)):  # keep only pairs with positive curvature
            S.append(sk)
            Y.append(yk)
            rho.append(1.0 / sy)
            if len(S) > max(config.history, 1):
                S.pop(0)
                Y.pop(0)
                rho.pop(0)
        x, E, g, state = x_new, E_new, g_new, state_new
        gnorm = gradient_norm(g, config.gnorm)
        if gnorm <= config.gtol or E <= 1e-30 or levelled_off(E):
            status = "converged"
            break
    return RefineResult(x * s, rots.to_matrices(state), E * s * s, gnorm, it, status)
