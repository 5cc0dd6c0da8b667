"""Regularized SDP sensor-network localization (Funiak et al. 2008 §VI-E (ii); Biswas et al. [1]_).

Inequality form with the spreading regularizer: module 0 is put at the origin and the Gram matrix
Y of the other centres solves

.. math::

    \\max_{Y \\succeq 0} \\operatorname{tr} Y \\quad \\text{s.t.} \\quad
    Y_{ii} + Y_{jj} - 2 Y_{ij} \\le d^2 \\ \\text{for every observed pair},

with d the model's contact spacing (two radii); a pair with module 0 constrains Y_jj alone. The
trace, the summed squared distance to module 0, spreads the embedding so it does not fold up. It
is solved in dual form (one weight per observed pair, ``sum_e w_e E_e - I`` PSD), whose sparsity is
the contact graph's, so Clarabel's chordal decomposition applies; Y is the completed dual of the
PSD constraint, and the centres are its top ``dim`` eigenvectors. The solve still grows quickly
with the module count, so :data:`SDP_MAX_NODES` guards it: a larger component raises
:class:`SolverError` with a plain message instead of running out of time or memory.

References
----------
.. [1] P. Biswas, T.-C. Liang, T.-C. Wang, Y. Ye, "Semidefinite programming based algorithms for
   sensor network localization", ACM TOSN 2(2), 2006.
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy import sparse
from scipy.linalg import eigh

from decentral.ensemble.baselines.common import FINAL_REFINE, run_per_component
from decentral.ensemble.hierarchical import LocalizationResult
from decentral.ensemble.problem import EnsembleProblem
from decentral.ensemble.refine import RefineConfig
from decentral.errors import SolverError

__all__ = ["SDP_MAX_NODES", "sdp_positions", "sdp_localize"]

#: largest component the SDP baseline accepts by default
SDP_MAX_NODES = 1200


def sdp_positions(problem: EnsembleProblem, max_nodes: int | None = None,
                  time_limit: float | None = None) -> tuple[np.ndarray, dict]:
    """Centres (n, dim) of a connected problem from the regularized SDP, and solver facts.

    Raises :class:`SolverError` if the problem exceeds ``max_nodes`` (default
    :data:`SDP_MAX_NODES`), the solver fails, or it exceeds ``time_limit`` seconds (wall clock).
    """
    import cvxpy as cp

    if max_nodes is None:
        max_nodes = SDP_MAX_NODES

    n, d = problem.n, problem.dim
    if n > max_nodes:
        raise SolverError(f"the regularized SDP is limited to {max_nodes} modules per component "
                          f"(got {n}); use --method ncut for large ensembles")
    if n <= d:
        return np.zeros((n, d)), {"status": "trivial"}
    P = problem.pairs()
    m = n - 1
    a, b = P[:, 0] - 1, P[:, 1] - 1  # indices in Y; -1 is the anchored module 0
    e = np.arange(len(P))
    rows, cols, vals = [], [], []
    for u, v, sign in ((a, a, 1.0), (b, b, 1.0), (a, b, -1.0), (b, a, -1.0)):
        ok = (u >= 0) & (v >= 0)
        rows.append(v[ok] * m + u[ok])  # column-major position of Y[u, v]
        cols.append(e[ok])
        vals.append(np.full(int(ok.sum()), sign))
    A = sparse.csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(m * m, len(P)))
    scale = 2.0  # contact spacing in radii; the program is solved in module radii
    w = cp.Variable(len(P), nonneg=True)
    con = cp.reshape(A @ w, (m, m), order="F") - np.eye(m) >> 0
    prob = cp.Problem(cp.Minimize(scale**2 * cp.sum(w)), [con])
    try:
        # a baseline's starting point needs no more than 1e-5 relative accuracy (about 35 % faster)
        limit = {} if time_limit is None else {"time_limit": float(time_limit)}
        with warnings.catch_warnings():  # an inaccurate solve is reported through the status below
            warnings.simplefilter("ignore", UserWarning)
            prob.solve(solver="CLARABEL", verbose=False, tol_gap_abs=1e-5, tol_gap_rel=1e-5, tol_feas=1e-6,
                       **limit)
    except cp.error.SolverError as err:
        raise SolverError(f"regularized SDP: solver failed ({err})") from None
    if prob.status not in ("optimal", "optimal_inaccurate") or con.dual_value is None:
        raise SolverError(f"regularized SDP: solver status {prob.status}")
    Y = 0.5 * (con.dual_value + con.dual_value.T)
    vals_, vecs = eigh(Y, subset_by_index=[m - d, m - 1])
    x = np.zeros((n, d))
    x[1:] = vecs[:, ::-1] * np.sqrt(np.maximum(vals_[::-1], 0.0))
    return x * problem.radius, {"status": prob.status, "rank_energy": float(vals_.sum() / max(np.trace(Y), 1e-300))}


def sdp_localize(problem: EnsembleProblem, refine_config: RefineConfig | None = FINAL_REFINE,
                 max_nodes: int | None = None) -> LocalizationResult:
    """Localize by the regularized SDP, then fit orientations and refine (None: no refinement).

    Raises :class:`SolverError` when a component exceeds ``max_nodes`` (default
    :data:`SDP_MAX_NODES`) or the solver fails.
    """
    facts: dict = {"method": "sdp"}

    def initial(sub):
        x, f = sdp_positions(sub, max_nodes)
        facts.setdefault("solver", []).append(f)
        return x, None, np.zeros(sub.n)

    return run_per_component(problem, initial, refine_config, facts)
