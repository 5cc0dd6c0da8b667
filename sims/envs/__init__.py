"""PettingZoo environments. Import the versioned module, e.g. ``sims.envs.relative_localization_v0``."""

__all__: list[str] = []
