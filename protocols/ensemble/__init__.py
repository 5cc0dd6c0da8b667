"""protocols.ensemble: messages and aggregation/dissemination halves of Funiak et al.'s distributed
localization (§V), and the pure reductions its group leaders perform."""

from protocols.ensemble.aggregation import Convergecast, combine, split_by_subtree
from protocols.ensemble.leader import CutPlan, cut_clusters, moved_target, plan_merge
from protocols.ensemble.messages import (
    PHASES,
    SUBPHASE_OF,
    Ack,
    ClusterClaim,
    Command,
    Hello,
    Join,
    PoseShare,
    Report,
    TreeFlood,
)

__all__ = [
    "PHASES",
    "SUBPHASE_OF",
    "Ack",
    "ClusterClaim",
    "Command",
    "Convergecast",
    "CutPlan",
    "Hello",
    "Join",
    "PoseShare",
    "Report",
    "TreeFlood",
    "combine",
    "cut_clusters",
    "moved_target",
    "plan_merge",
    "split_by_subtree",
]
