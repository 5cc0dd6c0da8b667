"""The ``"alternating"`` refiner: exact block-coordinate descent (Kabsch fits, one Laplacian solve) with Anderson mixing."""

from __future__ import annotations

import numpy as np

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

__all__ = ["refine_alternating"]


def refine_alternating(problem: EnsembleProblem, position: np.ndarray, rotation: np.ndarray,
                        config: RefineConfig, fixed: np.ndarray | None = None,
                        elimination: np.ndarray | None = None) -> RefineResult:
    n, d, s = problem.n, problem.dim, problem.radius
    z, x, R0 = in_radii(problem, position, rotation)
    if problem.num_observations == 0:
        return no_observations(x, R0, s)
    lap, rots, held, fit, inc = block_setup(problem, z, R0, fixed, config.ordering, elimination)

    def gradient(r):  # position gradient of the free modules (held ones do not move)
        g = inc.gradient(r)
        if held is not None:
            g[held] = 0.0
        return g

    def evaluate(half, state):  # half = (c_j - c_i) / 2 per observation
        rz = rots.apply(state)
        r = rz - half
        return state, rz, r, 0.5 * float(np.einsum("ea,ea->", r, r))

    def energy(c):  # best orientations for the centres c (local step) and the resulting cost
        half = inc.half(c)
        return evaluate(half, fit(half))

    # start from the given orientations if they are better than the fitted ones
    R, rz, r, E = energy(x)
    given = evaluate(inc.half(x), rots.from_matrices(rotation))
    if given[3] < E:
        R, rz, r, E = given
    levelled_off = DecreaseTest(config, E)
    dF: list[np.ndarray] = []
    dG: list[np.ndarray] = []
    f_prev = g_prev = None
    it = 0
    status = "max_iter"
    gnorm = gradient_norm(gradient(r), config.gnorm)
    while it < config.max_iter:
        if gnorm <= config.gtol or E <= 1e-30:
            status = "converged"
            break
        it += 1
        g = lap.solve(2.0 * rz, x)  # global step: best centres for the current orientations
        f = g - x
        if f_prev is not None and config.history > 0:
            dF.append((f - f_prev).ravel())
            dG.append((g - g_prev).ravel())
            if len(dF) > config.history:
                dF.pop(0)
                dG.pop(0)
        f_prev, g_prev = f, g
        x_new = g
        if dF:
            Fm = np.stack(dF, 1)
            # Anderson weights from the normal equations of the small (<= history) least-squares
            # problem, lightly regularized (faster than an SVD-based lstsq on a tall matrix)
            G = Fm.T @ Fm
            G.flat[:: G.shape[0] + 1] += 1e-12 * np.trace(G) + 1e-300
            try:
                gamma = np.linalg.solve(G, Fm.T @ f.ravel())
            except np.linalg.LinAlgError:
                gamma, *_ = np.linalg.lstsq(Fm, f.ravel(), rcond=None)
            x_new = g - (np.stack(dG, 1) @ gamma).reshape(n, d)
        R_new, rz_new, r_new, E_new = energy(x_new)
        if dF and not E_new <= E:
            # safeguard: the accelerated point is worse; take the plain (monotone) sweep. The
            # history is kept: clearing it on every rejection (38 of 100 sweeps on a 3D solid)
            # threw away the slow modes it had learned, and the plain sweeps crawl along them.
            x_new = g
            R_new, rz_new, r_new, E_new = energy(g)
        x, R, rz, r, E = x_new, R_new, rz_new, r_new, E_new
        gnorm = gradient_norm(gradient(r), config.gnorm)
        if gnorm <= config.gtol or E <= 1e-30 or levelled_off(E):
            status = "converged"
            break
    return RefineResult(x * s, rots.to_matrices(R), E * s * s, gnorm, it, status)
