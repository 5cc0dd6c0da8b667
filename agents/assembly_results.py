"""What an assembly agent reports: its estimates, why an assembly is unplaced, convergence and neighbours.

The read-out half of :class:`agents.assembly.AssemblyAgent`, kept apart from its sensing, handlers and
ADMM phases: poses relative to the agent's own root frame (Liu et al. 2024 eq. (19)) from the gossip
table's rows of the current step or from the joint solution the window started at
(:class:`agents.window_start.WindowStart`), the reason code of each assembly it cannot place, and the
flags and neighbour sets the runtime reads. It reads the agent's state and changes nothing.
"""

from __future__ import annotations

import numpy as np

from agents.agent_config import AgentConfig
from agents.window_start import WindowStart
from decentral.admm import ConsensusState, PairState
from decentral.geometry import wrap_angle
from decentral.observations import PlanarPose
from protocols.admm_rounds import AdmmRounds
from protocols.admm_values import AdmmInbox
from protocols.pose_gossip import PoseGossip, pose_row

__all__ = ["AssemblyResults"]


class AssemblyResults:
    """The results of an :class:`agents.assembly.AssemblyAgent` (a mixin over the agent's state, read only)."""

    config: AgentConfig
    _index: dict[str, int]
    _step: int | None
    _pairs: dict[str, PairState]
    _consensus: ConsensusState
    _inbox: AdmmInbox
    _rounds: AdmmRounds
    _gossip: PoseGossip
    _start: WindowStart
    _watchers: set[str]

    @property
    def converged(self) -> bool:
        """Whether its pairs' residuals and its consensus change are below tolerance with fresh inputs."""
        return self._rounds.converged

    @property
    def complete(self) -> bool:
        """Whether this window started from the joint solution of every live agent's forms (its own, or the
        reference's): only then is a converged ADMM the centralized answer, not the consensus of a partial
        problem (forms or configurations still missing)."""
        return bool(self._start.complete) or self.config.share_forms != "every"

    @property
    def without(self) -> tuple[str, ...]:
        """Agents whose forms this window's complete set lacked (given up on as down), sorted: a converged
        window is then the joint estimate of the others' data only."""
        return tuple(sorted(self._start.without)) if self._start.complete else ()

    @property
    def ready(self) -> bool:
        """Whether its consensus poses are in the pinned gauge."""
        return self._consensus.ready

    @property
    def observers(self) -> tuple[str, ...]:
        """Assemblies that observe this one: from their ADMM values, or from the last complete set of forms
        (its pairs name observer and target; an exact window sends no ADMM values)."""
        return tuple(sorted(set(self._inbox.observers) | self._watchers))

    @property
    def neighbours(self) -> tuple[str, ...]:
        """Assemblies it observes or is observed by in the current window."""
        return tuple(sorted(set(self._pairs) | set(self.observers)))

    @property
    def ages(self) -> dict[str, int]:
        """Rounds since the newest value used from each neighbour (0 or 1: fresh)."""
        return dict(self._rounds.ages)

    def unplaced(self, placed: dict[str, PlanarPose] | None = None) -> dict[str, str]:
        """Why each assembly missing from :meth:`estimates` (or ``placed``) is missing (a reason code of
        :data:`decentral.unplaced.REASONS`).

        The joint placement test's reason when this agent holds every agent's forms of the step;
        otherwise ``no_consensus`` (it cannot tell a lost row from an assembly nobody saw).
        """
        placed = self.estimates() if placed is None else placed
        return {name: (self._start.why.get(name, "no_consensus") if self._start.complete else "no_consensus")
                for name in self.config.assemblies if name != self.name and name not in placed}

    def estimates(self) -> dict[str, PlanarPose]:
        """Pose of every assembly it can place at the current step, in its own root frame (eq. (19)).

        From the gossip table's rows of the current step; an assembly whose row of this step has not
        arrived (lost copies) is taken from the joint solution of the step's shared forms when this
        agent holds every agent's forms (that solution is the ADMM's fixed point, restricted to the
        assemblies tied to the gauge, the same placement rule as the consensus). While the ADMM has not
        converged, or when it ran no ADMM round in this window, the joint solution this agent holds (of every live agent's
        forms, or of those that came before the wait for them ended) gives the step's placements instead:
        an iterate on its way is no estimate (a neighbour without the set pulls it off the fixed point for
        a while, and its rows reach this agent's table). In an exact window (every live agent's forms, its own
        pairs as they are now) the joint solution is the answer, whatever rows arrive.
        """
        if self._step is None:
            return {}
        if self._start.fallback and (self._exact() or not self.converged or not self._start.admm_ran):
            # (in an exact window, or without an ADMM round of its own here, the joint solution is this window's
            # answer: rows that other agents' ADMM wrote into the gossip table while they ran without the set are
            # iterates on their way, once 11 km off at 50 % loss. An exact window runs rounds to answer such a
            # neighbour; its table then held the neighbour's iterates, and a window revised in the background
            # reported them converged, 5-78 mm off, on an 8-ring with 10 % loss and busy cores)
            return self._relative_to_own(self._rows_of(self._start.fallback))
        me = self._gossip.rows.get(self._index[self.name])
        if not self._consensus.ready or me is None or int(me[1]) != self._step:
            return {}
        rows = {i: row for i, row in self._gossip.rows.items() if int(row[1]) == self._step}
        if self._start.complete:
            for (name, step), (R, p) in self._start.seeds.items():
                i = self._index.get(name)
                if step == self._step and i is not None and i not in rows:
                    rows[i] = pose_row(i, step, 0, R, p)
            # (an assembly whose yaw relative to this agent is not determined is left out, never guessed)
            rows = {i: row for i, row in rows.items()
                    if i == self._index[self.name] or (self.config.assemblies[i], self._step) in self._start.placeable}
        return self._relative_to_own(rows)

    def _rows_of(self, poses: dict[str, tuple], step: int | None = None) -> dict[int, np.ndarray]:
        """Poses ``assembly -> (R, p)`` of ``step`` (default: this step) as gossip-table rows (index, step, round,
        x, y, z, yaw)."""
        step = self._step if step is None else step
        return {self._index[name]: pose_row(self._index[name], step, 0, R, p) for name, (R, p) in poses.items()}

    def _relative_to_own(self, rows: dict[int, np.ndarray]) -> dict[str, PlanarPose]:
        """Rows of this step (root frames in the gauge) as poses in this agent's root frame (eq. (19))."""
        me = rows.get(self._index[self.name])
        if me is None:
            return {}
        c, s = np.cos(me[6]), np.sin(me[6])
        out = {}
        for i, row in rows.items():
            if i == self._index[self.name]:
                continue
            d = row[3:6] - me[3:6]
            p = np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1], d[2]])  # Liu et al. 2024 eq. (19)
            out[self.config.assemblies[i]] = PlanarPose(p, float(wrap_angle(row[6] - me[6])))
        return out
