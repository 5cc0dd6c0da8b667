"""agents.modules: one agent per module of an ensemble (Funiak et al. 2008 §V distributed localization)."""

from agents.modules.agent import LevelState, ModuleAgent, ModuleConfig
from agents.modules.batched import BatchedRefinement

__all__ = ["BatchedRefinement", "LevelState", "ModuleAgent", "ModuleConfig"]
