"""Consensus-ADMM over per-pair relaxed subproblems: the math every assembly agent runs (Liu et al. 2024).

The joint window cost is split by directed observing pair; each pair keeps local copies of its two
assemblies' poses (:class:`PairState`), each assembly owns its consensus poses with its odometry
(:class:`ConsensusState`), and both updates are proximal problems (:mod:`decentral.admm.prox`) over
quadratic forms (:mod:`decentral.admm.forms`); agents that share their forms start at the joint
solution (:func:`solve_joint`). docs/admm_method.md gives the derivation, the metric, the gauge and
why plain ADMM is slow on rings.
"""

from decentral.admm.config import AdmmConfig
from decentral.admm.consensus import ConsensusState
from decentral.admm.forms import LocalProblem, Pose2, quadratic_form
from decentral.admm.joint import JointSolution, solve_joint
from decentral.admm.pair import PairState
from decentral.admm.prox import (
    ProxSolution,
    balance_penalty,
    pair_metric,
    pose_columns,
    scalar_metric,
    solve_prox,
    solve_prox_metric,
)

__all__ = [
    "AdmmConfig",
    "LocalProblem",
    "ProxSolution",
    "quadratic_form",
    "solve_prox",
    "solve_prox_metric",
    "scalar_metric",
    "pose_columns",
    "pair_metric",
    "solve_joint",
    "JointSolution",
    "balance_penalty",
    "PairState",
    "ConsensusState",
    "Pose2",
]
