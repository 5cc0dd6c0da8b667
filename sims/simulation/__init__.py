"""The simulation: the world and its cameras, scenarios, rendering, the swarm, ensembles, the PettingZoo envs.

Everything here makes synthetic data and ground truth; it imports only :mod:`sims.io` among the
other parts of :mod:`sims`.
"""

__all__: list[str] = []
