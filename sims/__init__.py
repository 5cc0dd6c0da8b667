"""sims: worlds and scenarios, OpenCV rendering, the PettingZoo env, experiments and the CLI."""

__all__: list[str] = []
