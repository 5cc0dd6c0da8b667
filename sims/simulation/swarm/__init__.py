"""Kanovsky's camera swarm: one-node unicycle robots with field-of-view-limited cameras, on-board
EKF tracking of each other, and reports shared over the simulated radio."""

from sims.simulation.swarm.config import SwarmConfig
from sims.simulation.swarm.robot import SwarmRobot, Track
from sims.simulation.swarm.sim import PairError, StepReport, SwarmRun, SwarmSim, run_swarm
from sims.simulation.swarm.world import SwarmWorld, wander_actions

__all__ = [
    "SwarmConfig",
    "SwarmWorld",
    "SwarmRobot",
    "Track",
    "SwarmSim",
    "SwarmRun",
    "StepReport",
    "PairError",
    "run_swarm",
    "wander_actions",
]
