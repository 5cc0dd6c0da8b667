"""Baselines that the protocols' costs are measured against (not used by the agents themselves)."""

__all__: list[str] = []
