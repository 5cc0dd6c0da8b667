"""The lab: studies (grids of runs, their store and report) and the experiments of the papers' tables.

The lab calls the runners (:mod:`sims.runners`) and the simulation (:mod:`sims.simulation`); neither
of those imports the lab.
"""

__all__: list[str] = []
