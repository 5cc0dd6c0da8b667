"""Liu et al. 2024 §V-E (Fig. 4): a still observer and one target that reconfigures while it is watched.

The target's configuration goes through phases of ``phase_steps`` steps each, while it drifts and slowly turns: (a) two nodes, one
partly hidden behind the root; (b) a third node joins beside them, in clear view; (c) the hidden
node moves out to the other side (three clear nodes); (d) a node leaves and another joins on top
(a 3D stack); (e) a node joins behind the root again. The observer stands low (on the floor by
default) so that nodes line up along its line of sight and occlude each other.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sims.simulation.scenarios.base import Scenario, ScenarioConfig
from sims.simulation.world.motion import jitter, still
from sims.simulation.world.rigs import strut_camera
from sims.simulation.world.shapes import NODE_RADIUS, SPACING, Shape
from sims.simulation.world.world import AssemblyTrack, World

__all__ = ["ReconfigConfig", "Reconfig", "PHASES"]

s = SPACING
#: the target's configurations, phase by phase: node id -> centre in H_r (root 10 at the origin)
PHASES = (
    {10: (0, 0, 0), 11: (s, 0, 0)},
    {10: (0, 0, 0), 11: (s, 0, 0), 12: (0, s, 0)},
    {10: (0, 0, 0), 11: (0, -s, 0), 12: (0, s, 0)},
    {10: (0, 0, 0), 11: (0, -s, 0), 13: (0, -s / 2, s * np.sqrt(3) / 2)},
    {10: (0, 0, 0), 11: (0, -s, 0), 13: (0, -s / 2, s * np.sqrt(3) / 2), 14: (s, 0, 0)},
)
del s


def _phase_shape(nodes: dict) -> Shape:
    ids = tuple(nodes)
    centres = np.asarray([nodes[i] for i in ids], dtype=float)
    struts = tuple((ids[0], i) for i in ids[1:])
    return Shape(ids, centres, struts)


@dataclass(frozen=True)
class ReconfigConfig(ScenarioConfig):
    """Parameters of :class:`Reconfig` (plus those of :class:`ScenarioConfig`).

    Attributes
    ----------
    phase_steps : int
        Steps spent in each configuration phase (the run cycles through :data:`PHASES`).
    distance : float
        Distance [m] from the observer to the target's root.
    observer_height : float
        Height [m] of the surface the observer stands on (0: the floor).
    heading_offset_deg : float
        The target's x axis points away from the observer, turned by this angle [deg], so the node
        behind the root is partly (not wholly) hidden.
    target_drift : float
        Amplitude [m] of the target's slow drift.
    sweep_deg : float
        Amplitude [deg] of the target's slow heading sweep about ``heading_offset_deg``: the node
        behind the root goes from hidden to clear and back.
    sweep_period : float
        Period [s] of that sweep.
    """

    steps: int = 125
    phase_steps: int = 25
    distance: float = 1.6
    observer_height: float = 0.0
    heading_offset_deg: float = 15.0
    target_drift: float = 0.05
    sweep_deg: float = 12.0
    sweep_period: float = 10.0

    def __post_init__(self):
        super().__post_init__()
        if self.phase_steps < 1:
            raise ValueError("phase_steps must be positive")
        if self.distance <= 0.3 or self.sweep_period <= 0:
            raise ValueError("distance must exceed 0.3 m and sweep_period be positive")


class Reconfig(Scenario):
    """A still observer watching one target change its configuration (Liu et al. 2024 Fig. 4)."""

    name = "reconfig"
    Config = ReconfigConfig

    def make_world(self, rng: np.random.Generator) -> World:
        c = self.config
        times = np.arange(c.steps) * c.dt
        obs_shape = _phase_shape({0: (0, 0, 0), 1: (SPACING, 0, 0)})
        oxy, oyaw = still(c.steps, (0.0, 0.0), -np.pi / 2)
        camera = strut_camera("A0", "cam0", at=(SPACING / 2, 0.0, 0.0), look_yaw=np.pi / 2)
        # the camera sits at (0.125, 0.05) in the observer's root frame: in W that is (0.05, -0.125)
        cam_xy = np.array([0.05, -SPACING / 2])
        target_xy = cam_xy + np.array([c.distance, 0.0])
        txy, _ = jitter(c.steps, c.dt, target_xy, 0.0, rng, amplitude=c.target_drift, yaw_amplitude=0.0)
        sweep = np.sin(2 * np.pi * times / c.sweep_period + rng.uniform(0, 2 * np.pi))
        tyaw = np.radians(c.heading_offset_deg + c.sweep_deg * sweep)
        phase = np.minimum(np.arange(c.steps) // c.phase_steps, len(PHASES) - 1)
        shapes = tuple(_phase_shape(PHASES[int(i)]) for i in phase)
        assemblies = (
            AssemblyTrack("A0", c.observer_height, oxy, oyaw, (obs_shape,) * c.steps),
            AssemblyTrack("A1", 0.0, txy, tyaw, shapes),
        )
        return World(NODE_RADIUS, times, assemblies, (camera,), {"phase": phase.tolist()})


SCENARIO = Reconfig
