"""ADMM state of one directed observing pair (:class:`PairState`): its local copies, scaled duals and penalty."""

from __future__ import annotations

import numpy as np

from decentral.admm.config import AdmmConfig
from decentral.admm.forms import LocalProblem
from decentral.admm.prox import balance_penalty, pair_metric, pose_columns, scalar_metric, solve_prox_metric
from decentral.geometry import rot2, yaw_of

__all__ = ["PairState"]


def _metric_norm2(d: np.ndarray, dz: float, P: np.ndarray, w_z: float) -> float:
    """``||Delta||^2`` in the metric ``(P, w_z)`` of a pose difference given as columns ``d`` (2, 3) and height ``dz``."""
    return float(np.sum((d @ P) * d) + w_z * dz * dz)


class PairState:
    """ADMM state of one directed observing pair ``observer -> target``, kept by the observer's agent.

    The pair's local copies ``y`` cover the window steps at which it has visual factors. Call
    :meth:`set_problem` whenever the window or the factors change (copies and duals of the keys that
    remain are kept: the warm start), then :meth:`iterate` once per ADMM round with the newest
    consensus values. Its penalty on key ``i`` is ``rho * P_i`` (and ``rho * w_z_i`` on the height):
    the information metric of :func:`pair_metric` (``AdmmConfig.metric = "information"``) or the
    scalar one, ``P_i = diag(c_p, c_R, c_R)`` with the pair's mean curvatures (``"scalar"``).
    """

    def __init__(self, observer: str, target: str, config: AdmmConfig):
        self.observer, self.target, self.config = observer, target, config
        self.problem: LocalProblem | None = None
        self.y: dict = {}  # key -> Pose2 (local copy)
        self.u: dict = {}  # key -> Pose2-shaped scaled dual (2x2, 3)
        self.z_used: dict = {}  # key -> Pose2 consensus used in the last dual update
        self.base: dict = {}  # key -> (P (3, 3), w_z): the metric before the scale rho
        self.rho = config.rho0
        self.r_R = self.r_p = self.c_R = self.c_p = np.inf
        self.iterations = 0
        self.certified = True
        self.live_prev: set = set()
        self.y_hat: dict = {}

    def set_problem(self, problem: LocalProblem) -> None:
        """Install the pair's factor cost for the current window, keeping state of surviving keys.

        A new key ``(assembly, step)`` whose predecessor ``(assembly, step - 1)`` had a dual starts
        with the predecessor's multiplier ``lambda = u P`` (``AdmmConfig.carry_duals``): consecutive
        frames see nearly the same scene, so the pair's "force" on the assembly is nearly the same, and
        the new step starts close to the ADMM fixed point instead of at ``u = 0``.
        """
        keep = set(problem.keys)
        carried = {}
        if self.config.carry_duals:
            for k in problem.keys:
                prev = (k[0], k[1] - 1)
                if k not in self.u and prev in self.u and prev in self.base:
                    carried[k] = (self.u[prev], self.base[prev])
        self.y = {k: v for k, v in self.y.items() if k in keep}
        self.u = {k: v for k, v in self.u.items() if k in keep}
        self.z_used = {k: v for k, v in self.z_used.items() if k in keep}
        self.problem = problem
        n = problem.n
        if n == 0:
            self.base = {}
            return
        if self.config.metric == "information":
            P, w_z = pair_metric(problem, self.config.metric_floor)
        else:
            c_p = float(np.trace(problem.M[:n, :n])) / n
            c_R = float(np.trace(problem.M[n:, n:])) / (2 * n)
            P, w_z = scalar_metric(np.full(n, c_R), np.full(n, c_p))
        base = {k: (P[i], float(w_z[i])) for i, k in enumerate(problem.keys)}
        for k, (u_prev, metric_prev) in carried.items():
            self.u[k] = u_prev
            self.base[k] = metric_prev  # converted to the new metric below
        for k, (uR, up) in list(self.u.items()):
            old = self.base.get(k)
            if old is not None and not (np.array_equal(old[0], base[k][0]) and old[1] == base[k][1]):
                # keep the unscaled multiplier lambda = U P fixed when the metric changes
                U = pose_columns(uR, up) @ old[0] @ np.linalg.inv(base[k][0])
                self.u[k] = (U[:, 1:], np.array([U[0, 0], U[1, 0], up[2] * old[1] / base[k][1]]))
        self.base = base

    def seed(self, values: dict) -> bool:
        """Start from a known joint solution: copies at ``values`` and the duals that make it a fixed point.

        At a minimizer ``x*`` of the joint cost the copy update returns ``y = x*`` exactly when
        ``grad f_e(x*) + rho u P = 0`` (stationarity of the prox problem at ``y = z = x*``), i.e.
        ``u = -grad f_e(x*) P^{-1} / rho`` per key; the consensus update then sees
        ``sum_e grad f_e + grad g_a = grad F(x*)``, which has no component along SO(2) x R^3, so ``x*``
        is a fixed point of the whole iteration Boyd et al. 2011 §3.3 (optimality conditions). Returns whether
        every key of the pair had a value.
        """
        prob = self.problem
        if prob is None or prob.n == 0 or not all(k in values for k in prob.keys):
            return False
        keys = prob.keys
        n = prob.n
        theta = np.array([float(yaw_of(values[k][0])) for k in keys])
        position = np.array([values[k][1] for k in keys], float)
        X = np.hstack([position[:, :2].T, rot2(theta).transpose(1, 0, 2).reshape(2, 2 * n)])
        grad = 2.0 * X @ prob.M  # d/dX tr(X M X^T)
        grad_z = 2.0 * (prob.M[:n, :n] @ position[:, 2] - prob.b_z)
        for i, k in enumerate(keys):
            P, w_z = self.base[k]
            G = grad[:, [i, n + 2 * i, n + 2 * i + 1]]
            U = -np.linalg.solve(P, G.T).T / self.rho
            self.u[k] = (U[:, 1:], np.array([U[0, 0], U[1, 0], -grad_z[i] / (self.rho * w_z)]))
            self.y[k] = (rot2(theta[i]), position[i].copy())
        self.y_hat = dict(self.y)
        self.z_used = dict(self.y)
        self.live_prev = set(keys)
        return True

    @property
    def rho_R(self) -> float:
        """Mean penalty on the rotation columns (for reports)."""
        if not self.base:
            return 0.0
        return self.rho * float(np.mean([0.5 * (P[1, 1] + P[2, 2]) for P, _ in self.base.values()]))

    @property
    def rho_p(self) -> float:
        """Mean penalty on the positions (for reports)."""
        if not self.base:
            return 0.0
        return self.rho * float(np.mean([P[0, 0] for P, _ in self.base.values()]))

    def metric(self, key) -> tuple[np.ndarray, float]:
        """The penalty ``(rho P, rho w_z)`` of one key."""
        P, w_z = self.base[key]
        return self.rho * P, self.rho * w_z

    @property
    def residuals(self) -> tuple[float, float, float, float]:
        """``(r_R, r_p, c_R, c_p)`` of the last iteration: primal residual and consensus change."""
        return self.r_R, self.r_p, self.c_R, self.c_p

    def converged(self) -> bool:
        """Primal residual and consensus change below the tolerances."""
        c = self.config
        return max(self.r_R, self.c_R) <= c.eps_rot and max(self.r_p, self.c_p) <= c.eps_pos

    def iterate(self, z: dict, ready: dict) -> tuple[dict, dict]:
        """One ADMM iteration: dual update with ``z``, penalty balancing, then the copy update.

        Parameters
        ----------
        z : dict
            key -> consensus value ``Pose2`` for every key whose assembly's consensus is known.
        ready : dict
            assembly name -> whether its consensus is in the pinned gauge (initialized).

        Returns
        -------
        values : dict
            key -> ``(y_hat + u)`` as ``Pose2``: what the owning assembly averages.
        metrics : dict
            key -> ``(P (3, 3), w_z)``: the weight of that value in the owner's consensus update.
        """
        prob = self.problem
        if prob is None or prob.n == 0:
            return {}, {}
        keys = prob.keys
        live = [k for k in keys if ready.get(k[0], False) and k in z]
        # dual update u += y - z and residuals (Boyd §3.3): only for copies that were live in the last
        # copy update too (a copy made before its assembly joined the gauge says nothing about z)
        both = [k for k in live if k in self.live_prev and k in self.y_hat]
        if both:
            rR = rp = sR = sp = 0.0
            r_w = s_w = 0.0
            have_prev = True
            for k in both:
                zR, zp = z[k]
                yR, yp = self.y_hat[k]
                uR, up = self.u.get(k, (np.zeros((2, 2)), np.zeros(3)))
                self.u[k] = (uR + yR - zR, up + yp - zp)
                rR += float(np.sum((yR - zR) ** 2))
                rp += float(np.sum((yp - zp) ** 2))
                P, w_z = self.base[k]
                r_w += _metric_norm2(pose_columns(yR - zR, yp - zp), yp[2] - zp[2], P, w_z)
                if k in self.z_used:
                    dR, dp = zR - self.z_used[k][0], zp - self.z_used[k][1]
                    sR += float(np.sum(dR ** 2))
                    sp += float(np.sum(dp ** 2))
                    s_w += _metric_norm2(pose_columns(dR, dp), dp[2], P, w_z)
                else:
                    have_prev = False
            self.r_R, self.r_p = np.sqrt(rR), np.sqrt(rp)
            self.c_R, self.c_p = (np.sqrt(sR), np.sqrt(sp)) if have_prev else (np.inf, np.inf)
            busy = max(self.r_R, self.c_R) > self.config.eps_rot or max(self.r_p, self.c_p) > self.config.eps_pos
            if self.iterations % self.config.balance_every == 0 and have_prev and s_w > 0 and busy:
                # Boyd §3.4.1 in the penalty metric: r = ||y - z||_P, s = rho ||z - z_prev||_P
                lo, hi = self.config.rho0 / self.config.rho_span, self.config.rho0 * self.config.rho_span
                new = balance_penalty(self.rho, np.sqrt(r_w), self.rho * np.sqrt(s_w), self.config, lo, hi)
                factor = new / self.rho
                if factor != 1.0:
                    self.rho = new
                    for k in self.u:
                        uR, up = self.u[k]
                        self.u[k] = (uR / factor, up / factor)
        else:
            self.r_R = self.r_p = self.c_R = self.c_p = np.inf
        for k in live:
            self.z_used[k] = z[k]
        self.live_prev = set(live)
        # copy update: prox towards z - u (live keys) or a vanishing pull to the last copy (others)
        n = prob.n
        P = np.zeros((n, 3, 3))
        G = np.zeros((n, 2, 3))
        w_z = np.zeros(n)
        g_z = np.zeros(n)
        theta0 = np.zeros(n)
        tiny = 1e-9
        for i, k in enumerate(keys):
            Pk, wk = self.base[k]
            if k in live:
                zR, zp = z[k]
                uR, up = self.u.get(k, (np.zeros((2, 2)), np.zeros(3)))
                Rb, pb = zR - uR, zp - up
                weight = self.rho
                theta0[i] = float(yaw_of(self.y[k][0])) if k in self.y else float(yaw_of(zR))
            else:
                Rb, pb = self.y.get(k) or z.get(k) or (np.eye(2), np.zeros(3))
                weight = tiny * self.rho
                theta0[i] = float(yaw_of(Rb))
            P[i], w_z[i] = weight * Pk, weight * wk
            G[i] = pose_columns(Rb, pb) @ P[i]
            g_z[i] = w_z[i] * pb[2]
        sol = solve_prox_metric(prob, P, G, w_z, g_z, theta0=theta0)
        self.certified = sol.certified
        R = sol.rotations
        self.y = {k: (R[i], sol.position[i]) for i, k in enumerate(keys)}
        # over-relaxation (Boyd §3.4.3): y_hat = alpha y + (1 - alpha) z
        a = self.config.alpha
        self.y_hat = {k: ((a * y[0] + (1 - a) * z[k][0], a * y[1] + (1 - a) * z[k][1]) if k in live else y)
                      for k, y in self.y.items()}
        self.iterations += 1
        values, metrics = {}, {}
        for k in keys:
            uR, up = self.u.get(k, (np.zeros((2, 2)), np.zeros(3)))
            if k not in live:
                uR, up = np.zeros((2, 2)), np.zeros(3)
            values[k] = (self.y_hat[k][0] + uR, self.y_hat[k][1] + up)
            metrics[k] = self.metric(k)
        return values, metrics
