"""The parameters of the consensus-ADMM (:class:`AdmmConfig`), shared by every agent of a run."""

from __future__ import annotations

from dataclasses import dataclass

from decentral.errors import InputError

__all__ = ["AdmmConfig"]


@dataclass(frozen=True)
class AdmmConfig:
    """Parameters of the consensus-ADMM.

    Attributes
    ----------
    rho0 : float
        Initial penalty scale: pair ``e`` penalizes key ``i`` with ``rho P_{e,i}``, ``rho = rho0`` at
        the start, ``P`` the information metric (or the mean curvature, ``metric="scalar"``).
    mu, tau : float
        Residual balancing: rescale ``rho`` by ``tau`` when one residual exceeds ``mu`` times the other.
    rho_span : float
        ``rho`` stays within ``[rho_init / rho_span, rho_init * rho_span]``.
    eps_rot : float
        Absolute tolerance on the rotation residuals (Frobenius norm of 2 x 2 blocks, ~ radians).
    eps_pos : float
        Absolute tolerance on the position residuals (metres).
    balance_every : int
        Adapt ``rho`` every this many pair iterations (1: every iteration).
    alpha : float
        Over-relaxation Boyd et al. 2011 §3.4.3 (1: none; 1.5-1.8 typical).
    metric : {"information", "scalar"}
        Penalty metric per key: the pair's diagonal Hessian block (:func:`pair_metric`) or a scalar
        per rotation / position (the pair's mean curvatures).
    metric_floor : float
        Regularization of the information metric, relative to its mean diagonal.
    carry_duals : bool
        A new step's duals start from the previous step's multipliers (:meth:`PairState.set_problem`).
    tail : float
        Convergence also needs the predicted remaining consensus change
        (:meth:`ConsensusState.remaining`) below ``tail`` times the tolerances.

    Defaults, measured on the 8-ring (K = 5, 6 steps, the first started from the shared forms; rounds
    of steps 2-6): information metric, rho0 0.3, floor 0.005, alpha 1.8, mu 100: 84, 95, 118, 91, 142;
    mu 1e6 (no balancing): 84, 101, 119, 102, 134; mu 3: 110, 133, 140, 118, 148; mu 10: 132, 138,
    155, 132, 181; rho0 1, floor 0.05, alpha 1.5, mu 3: 91, 105, 110, 103, 146; scalar metric (rho0 1,
    mu 3, alpha 1.5): 110, 115, 112, 133 (4 steps). On a seeded 8-ring step (one warm window): floor
    0.005 101, 0.05 109, 0.2 125, 1.0 175 rounds; scalar metric 135; rho0 0.1 ~200, 0.2 117, 0.5 135,
    1 ~220 (alpha 1.5, no balancing).
    """

    rho0: float = 0.3
    mu: float = 100.0
    tau: float = 2.0
    rho_span: float = 1e4
    eps_rot: float = 3e-5
    eps_pos: float = 3e-5
    balance_every: int = 1
    alpha: float = 1.8
    metric: str = "information"
    metric_floor: float = 0.005
    carry_duals: bool = True
    tail: float = 10.0

    def __post_init__(self) -> None:
        if not (self.rho0 > 0 and self.mu > 1 and self.tau > 1 and self.rho_span >= 1):
            raise InputError("need rho0 > 0, mu > 1, tau > 1, rho_span >= 1", field="admm")
        if not (self.eps_rot > 0 and self.eps_pos > 0):
            raise InputError("tolerances must be positive", field="admm")
        if not (isinstance(self.balance_every, int) and self.balance_every >= 1):
            raise InputError("balance_every must be an integer >= 1", field="admm")
        if not 0 < self.alpha < 2:
            raise InputError("alpha must be in (0, 2)", field="admm")
        if self.metric not in ("information", "scalar"):
            raise InputError("metric must be 'information' or 'scalar'", field="admm")
        if not self.metric_floor > 0:
            raise InputError("metric_floor must be positive", field="admm")
