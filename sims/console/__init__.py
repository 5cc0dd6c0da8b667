"""The operator's console: Kanovsky's operator loop over the swarm, the views of the swarm, of running
agents and of finished runs, and their MCAP export. The web page itself is :mod:`sims.console.app`
(the ``console`` extra); nothing here imports it."""

from sims.console.operator import OperatorSwarm, TickRecord
from sims.console.scene import Frame, svg
from sims.console.streams import StreamFollower
from sims.console.views import Replay, launch_rows, launch_series, swarm_frame

__all__ = ["OperatorSwarm", "TickRecord", "Frame", "svg", "StreamFollower", "Replay", "swarm_frame", "launch_rows",
           "launch_series"]
