"""What an assembly agent is told when it starts (:class:`AgentConfig`) and what its own sensors give it per
step (:class:`OwnStep`); the agent itself is :class:`agents.assembly.AssemblyAgent`."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from decentral.admm import AdmmConfig
from decentral.errors import InputError
from decentral.estimator import EstimatorConfig
from decentral.factors import NoiseModel
from decentral.observations import Camera, Detection, Odometry, Pose

__all__ = ["AgentConfig", "OwnStep"]


@dataclass(frozen=True)
class AgentConfig:
    """What an agent is told when it starts.

    Attributes
    ----------
    name : str
        Its assembly.
    assemblies : tuple of str
        Every assembly's name (the log header); rows of the gossip table are indices into it.
    reference : str
        The assembly whose agent pins the gauge (its pose at each window's first step).
    cameras : tuple of Camera
        Its own cameras.
    node_radius : float
        Node radius r_0 (m), for the radius depth cue.
    noise : NoiseModel
        Factor weights (the same model the centralized estimator uses).
    window : int
        Sliding-window length K.
    admm : AdmmConfig
        ADMM parameters.
    announce_every : int
        Re-announce the configuration to the current observers (unicast) every this many steps
        (repairs lost announcements; it is broadcast only when it changes).
    stale_rounds : int
        Inputs older than this many rounds keep the agent from reporting convergence.
    patience : int
        Rounds an ADMM step waits for a neighbour's value of the current iteration (while resending
        its own last value, which repairs lost copies) before going on with the newest value it has.
    share_forms : {"first", "every", "never"}
        When agents share their cost forms (by broadcast, ``admm.factors_delta``, or up the tree, ``admm.delta``)
        and start the ADMM at the joint solution they all compute from them: at the run's first step only
        (step 0, the cold start), at every step (default), or never (the gauge flood alone). See the module
        docstring.
    share_timeout : int
        Rounds after which an agent goes on with the forms it has (agents that never answered start
        from the gauge flood instead); below the reference in the tree, twice this (the reference's
        partial set comes down first).
    max_yaw_std : float
        With every agent's forms in hand, an assembly is reported only if the centralized estimator's
        placement test passes on the joint form (relative yaw determined, Laplace std at most this, rad;
        :class:`decentral.estimator.EstimatorConfig`).
    gossip_refresh : int
        The gossip table rides on an ADMM message to a neighbour only when it changed (a new row, a
        new step, or a pose moved by more than the ADMM tolerances) since it last went to that
        neighbour, or every this many rounds (repairs a lost copy).
    aggregation : {"tree", "broadcast"}
        How the forms of a window travel once the agent knows its place in the aggregation tree:
        up a spanning tree of the view graph to the reference agent and back down
        (:mod:`protocols.aggregation`, default), or broadcast by every agent (the cold start's way,
        used by both whenever an agent has no route to the reference yet).
    """

    name: str
    assemblies: tuple[str, ...]
    reference: str
    cameras: tuple[Camera, ...] = ()
    node_radius: float = 0.06
    noise: NoiseModel = field(default_factory=NoiseModel)
    window: int = 5
    admm: AdmmConfig = field(default_factory=AdmmConfig)
    announce_every: int = 5
    stale_rounds: int = 2
    patience: int = 6
    share_forms: str = "every"
    max_yaw_std: float = EstimatorConfig.max_yaw_std
    share_timeout: int = 24
    gossip_refresh: int = 10
    aggregation: str = "tree"

    def __post_init__(self) -> None:
        if self.name not in self.assemblies or self.reference not in self.assemblies:
            raise InputError("name and reference must be listed in assemblies", field="assemblies")
        if any(cam.assembly != self.name for cam in self.cameras):
            raise InputError("an agent only holds its own cameras", field="cameras")
        if not (isinstance(self.window, int) and self.window >= 1):
            raise InputError(f"window must be an integer >= 1, got {self.window!r}", field="window")
        if not (isinstance(self.announce_every, int) and self.announce_every >= 1):
            raise InputError("announce_every must be an integer >= 1", field="announce_every")
        if self.share_forms not in ("first", "every", "never"):
            raise InputError("share_forms must be 'first', 'every' or 'never'", field="share_forms")
        if self.aggregation not in ("tree", "broadcast"):
            raise InputError("aggregation must be 'tree' or 'broadcast'", field="aggregation")


@dataclass(frozen=True)
class OwnStep:
    """What an assembly's own sensors give at one step (no other assembly's data, no truth).

    Attributes
    ----------
    step : int
        Log step index.
    t : float
        Time (s).
    config : dict[int, ndarray]
        Own node id -> centre (3,) in the root horizontal frame.
    odometry : Odometry or None
        Own root motion since the previous step.
    detections : dict[str, tuple[Detection, ...]]
        Own camera key -> identified detections.
    mounts : dict[str, Pose]
        Own camera key -> strut pose overriding the default at this step.
    """

    step: int
    t: float
    config: dict[int, np.ndarray]
    odometry: Odometry | None = None
    detections: dict[str, tuple[Detection, ...]] = field(default_factory=dict)
    mounts: dict[str, Pose] = field(default_factory=dict)
