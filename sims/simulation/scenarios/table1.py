"""Liu et al. 2024 §V-D (Table I): one observer on a 0.75 m table, three moving targets on the floor.

The observer (a three-node line carrying one camera on its middle strut, tilted down) drifts slowly
on the table top; three targets of different configurations wander on the floor (one on a raised
mat: a different terrain) 0.8-2.5 m in front of it (1.85 m on average, as in the seed). Frames at 5 Hz.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sims.simulation.scenarios.base import Scenario, ScenarioConfig
from sims.simulation.world.motion import jitter, wander_many
from sims.simulation.world.rigs import strut_camera
from sims.simulation.world.shapes import LIBRARY, NODE_RADIUS, library_shape
from sims.simulation.world.world import AssemblyTrack, World

__all__ = ["Table1Config", "Table1"]


@dataclass(frozen=True)
class Table1Config(ScenarioConfig):
    """Parameters of :class:`Table1` (plus those of :class:`ScenarioConfig`).

    Attributes
    ----------
    table_height : float
        Height [m] of the observer's table top (its root is at ``table_height + r_0``).
    target_shapes : tuple[str, ...]
        Library shapes of the targets (one target each).
    target_floors : tuple[float, ...]
        Floor height [m] under each target (different terrains).
    ranges : tuple[float, ...]
        Distance [m] from the observer to each target's home.
    bearings_deg : tuple[float, ...]
        Bearing [deg] of each home from the camera axis (positive to the left).
    speed : float
        Target speed [m/s].
    wander_radius : float
        How far [m] targets roam from home before steering back.
    observer_drift : float
        Amplitude [m] of the observer's motion on the table.
    observer_yaw_drift : float
        Amplitude [rad] of the observer's heading changes.
    pitch_deg : float
        Downward tilt of the camera [deg].
    """

    steps: int = 150
    table_height: float = 0.75
    target_shapes: tuple = ("L", "triangle", "tower")
    target_floors: tuple = (0.0, 0.0, 0.03)
    # homes chosen so that the mean observer-target distance over a run is about 1.85 m, the paper's:
    # its Table I gives 0.039 m = 2.09 % (ours), 0.112 m = 5.38 % (AprilTag), 0.304 m = 16.9 %
    # (bearing), i.e. 1.8-2.1 m. (Homes of 1.8/2.5/2.0 m made it 2.47 m: nodes a quarter smaller.)
    # Targets wander up to ~0.7 m from home, so the nearest comes within ~0.8 m (edge of the view).
    ranges: tuple = (1.4, 1.8, 1.5)
    bearings_deg: tuple = (22.0, 0.0, -22.0)
    speed: float = 0.12
    wander_radius: float = 0.3
    observer_drift: float = 0.1
    observer_yaw_drift: float = 0.08
    pitch_deg: float = 18.0

    def __post_init__(self):
        super().__post_init__()
        n = len(self.target_shapes)
        if not (len(self.target_floors) == len(self.ranges) == len(self.bearings_deg) == n):
            raise ValueError("target_shapes, target_floors, ranges and bearings_deg must have equal lengths")
        unknown = [name for name in self.target_shapes if name not in LIBRARY]
        if unknown:
            raise ValueError(f"unknown target shape(s) {unknown}; known: {', '.join(LIBRARY)}")
        if min(self.ranges, default=1.0) <= 0 or self.speed < 0 or self.table_height < 0:
            raise ValueError("ranges must be positive; speed and table_height non-negative")


class Table1(Scenario):
    """One observer on a table and several wandering targets on the floor (Liu et al. 2024 Table I)."""

    name = "table1"
    Config = Table1Config

    def make_world(self, rng: np.random.Generator) -> World:
        c = self.config
        r0 = NODE_RADIUS
        times = np.arange(c.steps) * c.dt
        # the observer's camera strut faces +y of its root; turning the root by -90 deg makes it face +x of W
        observer_yaw = -np.pi / 2
        obs_shape = library_shape("line").with_ids([0, 1, 2])
        xy, yaw = jitter(c.steps, c.dt, (0.0, 0.0), observer_yaw, rng,
                         amplitude=c.observer_drift, yaw_amplitude=c.observer_yaw_drift)
        assemblies = [AssemblyTrack("A0", c.table_height, xy, yaw, (obs_shape,) * c.steps)]
        camera = strut_camera("A0", "cam0", at=(0.125, 0.0, 0.0), look_yaw=np.pi / 2,
                              pitch_down=np.radians(c.pitch_deg))
        homes = [(rng_ * np.cos(np.radians(b)), rng_ * np.sin(np.radians(b)))
                 for rng_, b in zip(c.ranges, c.bearings_deg)]
        starts = [(hx, hy, rng.uniform(-np.pi, np.pi)) for hx, hy in homes]
        paths = wander_many(c.steps, c.dt, starts, homes, rng, speed=c.speed, radius=c.wander_radius)
        next_id = 10
        for i, (name, floor, (pxy, pyaw)) in enumerate(zip(c.target_shapes, c.target_floors, paths)):
            shape = library_shape(name)
            shape = shape.with_ids(range(next_id, next_id + len(shape.ids)))
            next_id += 10
            assemblies.append(AssemblyTrack(f"A{i + 1}", floor, pxy, pyaw, (shape,) * c.steps))
        return World(r0, times, tuple(assemblies), (camera,))

SCENARIO = Table1
