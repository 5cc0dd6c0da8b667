"""What every scenario shares: the config base, the sensor hooks, and the run loop.

A scenario is one module holding a frozen config dataclass and one :class:`Scenario` subclass with
three hooks (house style 10): ``make_world(rng)`` builds the whole ground-truth timeline,
``reset(world, seed)`` prepares the sensors' noise streams, and ``observe(world, k, sensors)``
returns what the assemblies know at step ``k`` (an :class:`~decentral.observations.Step`).
:func:`simulate` drives them and returns the log and its ground truth.
"""

from __future__ import annotations

import difflib
from dataclasses import asdict, dataclass, field, fields, replace
from typing import Any, ClassVar

import numpy as np

from decentral.errors import InputError
from decentral.metrics import GroundTruth
from decentral.observations import ObservationLog, Step
from sims.io.validate import unknown_name
from sims.simulation.world.sensors import SensorNoise, detections_at, odometry_at, sensor_streams
from sims.simulation.world.truth import Truth
from sims.simulation.world.world import World

__all__ = ["ScenarioConfig", "Sensors", "Scenario", "Simulation", "simulate"]


@dataclass(frozen=True)
class ScenarioConfig:
    """Parameters every scenario has.

    Attributes
    ----------
    steps : int
        Number of time steps (frames) of the run.
    dt : float
        Time between steps [s] (0.2 s: the paper's 5 Hz frames).
    noise : bool
        ``False`` makes every sensor exact (no noise, drop-outs, missing odometry or outliers).
    sensors : SensorNoise
        The noise model used when ``noise`` is true.
    """

    steps: int = 100
    dt: float = 0.2
    noise: bool = True
    sensors: SensorNoise = field(default_factory=SensorNoise)

    def __post_init__(self):
        if int(self.steps) != self.steps or self.steps < 1:
            raise InputError(f"must be a positive integer, got {self.steps!r}", field="steps")
        if not (np.isfinite(self.dt) and self.dt > 0):
            raise InputError(f"must be positive, got {self.dt!r}", field="dt")

    @property
    def sensor_model(self) -> SensorNoise:
        """The sensor model in force (noiseless when ``noise`` is false)."""
        return self.sensors if self.noise else self.sensors.without_noise()


@dataclass
class Sensors:
    """Mutable sensor state of one run: the noise model and one generator per noise source."""

    noise: SensorNoise
    streams: dict
    visible: list = field(default_factory=list)


def _coerce(name: str, value: Any, default: Any) -> Any:
    """Check ``value`` against the type of the parameter's default; lists become tuples."""
    if name == "sensors":
        ok = isinstance(value, SensorNoise)
    elif isinstance(default, bool):
        ok = isinstance(value, (bool, np.bool_))
    elif isinstance(default, int) or default is None:
        ok = (isinstance(value, (int, np.integer)) and not isinstance(value, bool)) or (
            default is None and value is None
        )
    elif isinstance(default, float):
        ok = isinstance(value, (int, float, np.number)) and not isinstance(value, bool) and np.isfinite(value)
        value = float(value) if ok else value
    elif isinstance(default, tuple):
        ok = isinstance(value, (list, tuple))
        value = tuple(value) if ok else value
    else:
        ok = True
    if not ok:
        raise InputError(f"expected a value like {default!r}, got {value!r}", field=name)
    return value


class Scenario:
    """Base of every scenario: subclasses set ``name``, ``Config`` and implement ``make_world``."""

    name: ClassVar[str] = ""
    Config: ClassVar[type] = ScenarioConfig

    def __init__(self, config: ScenarioConfig | None = None, **params: Any):
        if config is not None and params:
            raise TypeError("give either a config or parameters, not both")
        self.config = config if config is not None else self.make_config(**params)

    @classmethod
    def make_config(cls, **params: Any) -> ScenarioConfig:
        """Build the config from keyword parameters; sensor-noise fields are accepted flat.

        Unknown parameters raise :class:`InputError` naming them.
        """
        own = {f.name for f in fields(cls.Config)}
        noise_fields = {f.name for f in fields(SensorNoise)}
        unknown = sorted(set(params) - own - noise_fields)
        if unknown:
            known = own | noise_fields
            # suggest for the first unknown name that is close to a known one
            first = next((u for u in unknown if difflib.get_close_matches(u, known, n=1, cutoff=0.6)), unknown[0])
            raise unknown_name(first, known, f"unknown parameter(s) {', '.join(unknown)} for scenario {cls.name!r}",
                               field="params")
        defaults = {f.name: f.default for f in fields(cls.Config)}
        defaults.update({f.name: f.default for f in fields(SensorNoise)})
        params = {k: _coerce(k, v, defaults[k]) for k, v in params.items()}
        mine = {k: v for k, v in params.items() if k in own}
        noisy = {k: v for k, v in params.items() if k in noise_fields and k not in own}
        try:
            config = cls.Config(**mine)
            if noisy:
                config = replace(config, sensors=replace(config.sensors, **noisy))
        except (TypeError, ValueError) as err:
            if isinstance(err, InputError):
                raise
            raise InputError(str(err), field="params") from None
        return config

    # --- hooks ----------------------------------------------------------------------------------

    def make_world(self, rng: np.random.Generator) -> World:
        """Build the ground-truth timeline of a run (all steps)."""
        raise NotImplementedError

    def reset(self, world: World, seed: int) -> Sensors:
        """Fresh sensors for ``world``: one noise stream per assembly's odometry and per camera."""
        names = [f"odometry/{a.name}" for a in world.assemblies] + [rig.key for rig in world.cameras]
        streams = sensor_streams(seed, names)
        return Sensors(self.config.sensor_model, streams)

    def observe(self, world: World, k: int, sensors: Sensors) -> Step:
        """What the assemblies know at step ``k``: configurations, odometry, detections, mounts."""
        config = {a.name: a.shapes[k].as_config() for a in world.assemblies}
        odometry = {}
        if k > 0:
            for a in world.assemblies:
                odo = odometry_at(world, a.name, k, sensors.noise, sensors.streams[f"odometry/{a.name}"])
                if odo is not None:
                    odometry[a.name] = odo
        detections, visible = detections_at(world, k, sensors.noise, sensors.streams)
        sensors.visible.append(visible)
        mounts = {rig.key: rig.mount_at(k) for rig in world.cameras if rig.mount_at(k) is not None}
        return Step(float(world.times[k]), config, odometry, detections, mounts)


@dataclass(frozen=True)
class Simulation:
    """One simulated run: its world, the observation log it produced, and the ground truth."""

    world: World
    log: ObservationLog
    truth: Truth


def simulate(scenario: Scenario, seed: int = 0) -> Simulation:
    """Run ``scenario`` with ``seed``: build its world, then observe every step.

    The world's randomness (shapes, motion) comes from the first child of ``SeedSequence(seed)``;
    the sensors' from per-source streams (see :func:`sims.simulation.world.sensors.sensor_streams`).
    """
    world_rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(1)[0])
    world = scenario.make_world(world_rng)
    sensors = scenario.reset(world, seed)
    steps = tuple(scenario.observe(world, k, sensors) for k in range(world.steps))
    log = ObservationLog(
        node_radius=world.node_radius,
        assemblies=tuple(a.name for a in world.assemblies),
        cameras={rig.key: rig.as_camera() for rig in world.cameras},
        steps=steps,
    )
    R = {a.name: np.stack([a.root_pose(k, world.node_radius).R for k in range(world.steps)]) for a in world.assemblies}
    p = {a.name: np.stack([a.root_pose(k, world.node_radius).p for k in range(world.steps)]) for a in world.assemblies}
    meta = {"scenario": scenario.name, "seed": int(seed), "config": asdict(scenario.config), **world.meta}
    truth = Truth(GroundTruth(world.times.copy(), R, p), world.node_radius, log.assemblies[0], tuple(sensors.visible), meta)
    return Simulation(world, log, truth)
