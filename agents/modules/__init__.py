"""agents.modules: one agent per module of an ensemble (seed 003 §V distributed localization)."""

from agents.modules.agent import LevelState, ModuleAgent, ModuleConfig

__all__ = ["LevelState", "ModuleAgent", "ModuleConfig"]
