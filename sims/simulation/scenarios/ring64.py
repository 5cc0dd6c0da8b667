"""The ``multi`` ring extended to 64 assemblies (for scaling benchmarks of the decentralized estimator).

Same world as :mod:`sims.simulation.scenarios.multi` (a ring, each camera aimed at the next assembly, a cyclic
view graph) with ``n_assemblies`` allowed up to 64. Node ids above 586 have no AprilTag 36h11 code,
so this scenario is for log-level runs, not for rendering.
"""

from __future__ import annotations

from dataclasses import dataclass

from sims.simulation.scenarios.base import ScenarioConfig
from sims.simulation.scenarios.multi import Multi, MultiConfig

__all__ = ["Ring64Config", "Ring64"]


@dataclass(frozen=True)
class Ring64Config(MultiConfig):
    """:class:`MultiConfig` with ``n_assemblies`` in 2..64 (default 32)."""

    n_assemblies: int = 32

    def __post_init__(self):
        ScenarioConfig.__post_init__(self)
        if not 2 <= self.n_assemblies <= 64:
            raise ValueError(f"n_assemblies must be in 2..64, got {self.n_assemblies!r}")
        if self.observers is not None and not 1 <= self.observers <= self.n_assemblies:
            raise ValueError("observers must be between 1 and n_assemblies")
        if not (isinstance(self.chord_every, int) and self.chord_every >= 0):
            raise ValueError(f"chord_every must be an integer >= 0, got {self.chord_every!r}")
        if not (isinstance(self.chord_skip, int) and self.chord_skip >= 2):
            raise ValueError(f"chord_skip must be an integer >= 2, got {self.chord_skip!r}")


class Ring64(Multi):
    """A ring of up to 64 assemblies, each watching the next."""

    name = "ring64"
    Config = Ring64Config


SCENARIO = Ring64
