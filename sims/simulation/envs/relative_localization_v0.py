"""Versioned entry point of the relative-localization PettingZoo env (house style 11)."""

from sims.simulation.envs.relative_localization import ENV_NAME, RelativeLocalizationEnv, parallel_env, raw_env

__all__ = ["ENV_NAME", "RelativeLocalizationEnv", "parallel_env", "raw_env"]
