"""Several observers and targets: assemblies on a ring, each camera watching the next (a cyclic view graph).

``n_assemblies`` assemblies (2-16 in the issue; up to 64 for scaling runs) stand on a circle, neighbours ``spacing`` metres apart, each with
a random configuration (library shapes and random lattice shapes). The first ``observers`` of them
carry a camera aimed at the next assembly around the ring (all of them by default: the view graph is
a cycle; cameras also see farther assemblies when they are in view). With ``chord_every = c > 0``
every ``c``-th assembly carries a second camera aimed across the ring at the assembly ``chord_skip``
places ahead: a cyclic view graph that is not a ring (chords close shorter loops). Everyone drifts
smoothly; halfway through the run the first observer's camera strut turns (a mount change announced
in the log).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from decentral.observations import Pose
from sims.simulation.scenarios.base import Scenario, ScenarioConfig
from decentral.geometry import rotz
from sims.simulation.world.motion import jitter
from sims.simulation.world.rigs import strut_camera
from sims.simulation.world.shapes import NODE_RADIUS, library_shape, random_lattice
from sims.simulation.world.world import AssemblyTrack, World

__all__ = ["MultiConfig", "Multi"]

_SHAPES = ("pair", "line", "L", "triangle", "square", "T", "zigzag", "stack", "tower", "lattice")


@dataclass(frozen=True)
class MultiConfig(ScenarioConfig):
    """Parameters of :class:`Multi` (plus those of :class:`ScenarioConfig`).

    Attributes
    ----------
    n_assemblies : int
        Assemblies on the ring (2-64).
    observers : int or None
        How many of them (the first ones) carry a camera; ``None``: all.
    spacing : float
        Distance [m] between ring neighbours.
    drift : float
        Amplitude [m] of each assembly's motion.
    yaw_drift : float
        Amplitude [rad] of each assembly's heading changes.
    mount_turn_deg : float
        Turn [deg] of the first observer's camera strut at mid-run (0: no mount change).
    chord_every : int
        Every this many assemblies (indices 0, c, 2c, ...) carry a second camera, ``cam1``, aimed at
        the assembly ``chord_skip`` places ahead (0: none, the plain ring).
    chord_skip : int
        How far ahead around the ring a chord camera looks (>= 2).
    """

    steps: int = 80
    n_assemblies: int = 6
    observers: int | None = None
    spacing: float = 1.8
    drift: float = 0.1
    yaw_drift: float = 0.08
    mount_turn_deg: float = 6.0
    chord_every: int = 0
    chord_skip: int = 2

    def __post_init__(self):
        super().__post_init__()
        if not (isinstance(self.chord_every, int) and self.chord_every >= 0):
            raise ValueError(f"chord_every must be an integer >= 0, got {self.chord_every!r}")
        if not (isinstance(self.chord_skip, int) and self.chord_skip >= 2):
            raise ValueError(f"chord_skip must be an integer >= 2, got {self.chord_skip!r}")
        if not 2 <= self.n_assemblies <= 64:
            raise ValueError(f"n_assemblies must be in 2..64, got {self.n_assemblies!r}")
        if self.observers is not None and not 1 <= self.observers <= self.n_assemblies:
            raise ValueError("observers must be between 1 and n_assemblies")


def _look_direction(centres: np.ndarray) -> float:
    """Yaw in H_r of the horizontal direction along which the shape extends least (the camera looks there)."""
    cands = np.linspace(-np.pi, np.pi, 24, endpoint=False)
    dirs = np.column_stack([np.cos(cands), np.sin(cands)])
    reach = (centres[:, :2] @ dirs.T).max(axis=0)
    return float(cands[int(np.argmin(reach))])


class Multi(Scenario):
    """A ring of assemblies, each watching the next."""

    name = "multi"
    Config = MultiConfig

    def make_world(self, rng: np.random.Generator) -> World:
        c = self.config
        n = c.n_assemblies
        n_obs = n if c.observers is None else c.observers
        times = np.arange(c.steps) * c.dt
        ring = c.spacing / (2 * np.sin(np.pi / n))
        angles = 2 * np.pi * np.arange(n) / n
        homes = ring * np.column_stack([np.cos(angles), np.sin(angles)])
        assemblies, cameras, kinds = [], [], []
        next_id = 0  # consecutive ids: 64 assemblies of <= 6 nodes stay below 587, so all carry a 36h11 tag
        for i in range(n):
            kind = _SHAPES[int(rng.integers(len(_SHAPES)))]
            kinds.append(kind)
            if kind == "lattice":
                shape = random_lattice(int(rng.integers(3, 7)), rng, p_up=0.2)
            else:
                shape = library_shape(kind)
            shape = shape.with_ids(range(next_id, next_id + len(shape.ids)))
            next_id += len(shape.ids)
            look = _look_direction(shape.centres)
            target = homes[(i + 1) % n] - homes[i]
            world_look = float(np.arctan2(target[1], target[0]))
            xy, yaw = jitter(c.steps, c.dt, homes[i], world_look - look, rng,
                             amplitude=c.drift, yaw_amplitude=c.yaw_drift)
            name = f"A{i}"
            assemblies.append(AssemblyTrack(name, 0.0, xy, yaw, (shape,) * c.steps))
            if i < n_obs:
                d = np.array([np.cos(look), np.sin(look), 0.0])
                reach = max(float((shape.centres @ d).max()), 0.0)
                at = (reach + NODE_RADIUS + 0.04) * d
                mounts = ()
                if i == 0 and c.mount_turn_deg:
                    turned = Pose(rotz(look + np.radians(c.mount_turn_deg)), at)
                    mounts = tuple(None if k < c.steps // 2 else turned for k in range(c.steps))
                cameras.append(strut_camera(name, "cam0", at=at, look_yaw=look, mounts=mounts))
            if c.chord_every and i % c.chord_every == 0 and c.chord_skip < n:
                across = homes[(i + c.chord_skip) % n] - homes[i]
                look2 = look + float(np.arctan2(across[1], across[0])) - world_look
                d2 = np.array([np.cos(look2), np.sin(look2), 0.0])
                reach2 = max(float((shape.centres @ d2).max()), 0.0)
                cameras.append(strut_camera(name, "cam1", at=(reach2 + NODE_RADIUS + 0.04) * d2, look_yaw=look2))
        return World(NODE_RADIUS, times, tuple(assemblies), tuple(cameras), {"shapes": kinds})


SCENARIO = Multi
