"""PettingZoo environments. Import the versioned module, e.g. ``sims.simulation.envs.relative_localization_v0``."""

__all__: list[str] = []
