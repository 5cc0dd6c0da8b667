"""An unobservable case: a one-node target that never moves, seen by a still observer.

A sphere looks the same from every side, so the target's yaw cannot be recovered: an estimator
must report it as not placeable rather than guess.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sims.simulation.scenarios.base import Scenario, ScenarioConfig
from sims.simulation.world.motion import still
from sims.simulation.world.rigs import strut_camera
from sims.simulation.world.shapes import NODE_RADIUS, SPACING, library_shape
from sims.simulation.world.world import AssemblyTrack, World

__all__ = ["SingleNodeConfig", "SingleNode"]


@dataclass(frozen=True)
class SingleNodeConfig(ScenarioConfig):
    """Parameters of :class:`SingleNode` (plus those of :class:`ScenarioConfig`).

    Attributes
    ----------
    distance : float
        Distance [m] from the camera to the target node.
    target_yaw_deg : float
        The target's true (unobservable) heading [deg].
    """

    steps: int = 30
    distance: float = 1.5
    target_yaw_deg: float = 40.0

    def __post_init__(self):
        super().__post_init__()
        if self.distance <= 0.3:
            raise ValueError("distance must exceed 0.3 m")


class SingleNode(Scenario):
    """A still observer and a still one-node target."""

    name = "single_node"
    Config = SingleNodeConfig

    def make_world(self, rng: np.random.Generator) -> World:
        c = self.config
        times = np.arange(c.steps) * c.dt
        obs = library_shape("pair").with_ids([0, 1])
        oxy, oyaw = still(c.steps, (0.0, 0.0), -np.pi / 2)
        camera = strut_camera("A0", "cam0", at=(SPACING / 2, 0.0, 0.0), look_yaw=np.pi / 2)
        target = library_shape("single").with_ids([10])
        txy, tyaw = still(c.steps, (0.05 + c.distance, -SPACING / 2), np.radians(c.target_yaw_deg))
        assemblies = (
            AssemblyTrack("A0", 0.0, oxy, oyaw, (obs,) * c.steps),
            AssemblyTrack("A1", 0.0, txy, tyaw, (target,) * c.steps),
        )
        return World(NODE_RADIUS, times, assemblies, (camera,))


SCENARIO = SingleNode
