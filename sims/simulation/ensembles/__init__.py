"""sims.simulation.ensembles: ensembles of modules for Funiak et al.'s internal localization.

The generator settles circular modules under gravity into 2D containers or rasterizes 3D solids into
a lattice, simulates the IR contact sensors and writes ``decentral.ensemble/1`` observations plus the
truth (:mod:`sims.simulation.ensembles.generator`); :mod:`sims.runners.ensemble_distributed` runs Funiak et al. 2008 §V as one
agent per module over the simulated network.
"""

from sims.simulation.ensembles.generator import (
    OBSERVATION_FORMAT,
    SHAPES,
    TRUTH_FORMAT,
    Ensemble,
    EnsembleSpec,
    generate,
    save_observations,
    save_truth,
)
from sims.simulation.ensembles.sensors import SensorModel

__all__ = [
    "OBSERVATION_FORMAT",
    "SHAPES",
    "TRUTH_FORMAT",
    "Ensemble",
    "EnsembleSpec",
    "SensorModel",
    "generate",
    "save_observations",
    "save_truth",
]
