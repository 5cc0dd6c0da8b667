"""What a module agent knows before it starts (:class:`ModuleConfig`) and its private state per level (:class:`LevelState`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from decentral.ensemble import HierarchyConfig
from protocols.ensemble.aggregation import Convergecast
from protocols.ensemble.leader import CutPlan

__all__ = ["LevelState", "ModuleConfig", "NOBODY", "NOT_YET"]

#: marks a convergecast step whose children reported before the module itself began it
NOT_YET = {"__not_yet__": None}
#: group id of a level-0 relay before it hears of any candidate
NOBODY = 2**62


@dataclass(frozen=True)
class ModuleConfig:
    """What a module knows before it starts (immutable).

    Attributes
    ----------
    module : int
        Its id.
    dim : int
        2 or 3.
    radius : float
        Module radius (metres).
    neighbours : ndarray of int, shape (k,)
        Modules it observed.
    z : ndarray, shape (k, dim)
        Its observations z_{module, neighbour} (own frame).
    hierarchy : HierarchyConfig
        Leaf size, abstraction size and refinement tolerances (shared with the centralized method).
    check_every : int
        Refinement iterations between two convergence checks.
    level_max_iter, top_max_iter : int
        Caps on refinement iterations below the top and at the top.
    step : float
        Damping of the position update (1 = jump to the local optimum).
    momentum : float
        Heavy-ball momentum of the position update (0 = plain damped Jacobi; 0.9 needs about a
        tenth of the iterations on a rotated seam).
    top_gtol : float
        Gradient tolerance (module radii) of the top-level refinement; below the top the
        hierarchy's ``level_refine.gtol`` applies.
    reliable : bool
        Acknowledge and retransmit every message (for lossy networks). A refinement iteration then
        waits until every share of that iteration has arrived, so a lossy run computes exactly what
        a lossless one does, at the price of the retransmissions and acknowledgements.
    retry_rounds : int
        Rounds without an acknowledgement before a retransmission.
    """

    module: int
    dim: int
    radius: float
    neighbours: np.ndarray
    z: np.ndarray
    hierarchy: HierarchyConfig = HierarchyConfig()
    check_every: int = 10
    level_max_iter: int = 400
    top_max_iter: int = 3000
    step: float = 1.0
    momentum: float = 0.9
    top_gtol: float = 1e-4
    reliable: bool = False
    retry_rounds: int = 3


class LevelState:
    """A module's private state for one level of the hierarchy."""

    __slots__ = (
        "group", "size", "leaf", "hops", "parent", "joined", "children", "nbrs", "nbr_next",
        "flood_in", "cluster", "cluster_in", "nbr_cluster", "cc", "plan", "boundary",
        "active", "iteration", "nbr_pose", "last_grad", "part_index", "previous",
    )

    def __init__(self, group: int, size: int = -1):
        self.group = group
        self.size = size
        self.leaf = False
        self.hops = -1
        self.parent = -1
        self.joined = False
        self.children: set[int] = set()
        self.nbrs: list[int] = []
        self.nbr_next: dict[int, int] = {}
        self.flood_in: list[tuple] = []
        self.cluster = -1
        self.cluster_in: list[tuple] = []
        self.nbr_cluster: dict[int, int] = {}
        self.cc: dict[str, tuple[Convergecast, dict]] = {}
        self.plan: CutPlan | None = None
        self.boundary: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self.active = False
        self.iteration = 0
        self.nbr_pose: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self.last_grad = np.inf
        self.part_index: dict[int, int] = {}
        self.previous: np.ndarray | None = None
