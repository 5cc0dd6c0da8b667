"""Phase 6 of a module agent: local refinement, one pose share per neighbour per iteration, stopped by the leader."""

from __future__ import annotations

import numpy as np

from decentral.ensemble import EnsembleProblem
from decentral.ensemble.model import fit_orientations, gradient
from decentral.ensemble.rotation import matrix_to_angle, matrix_to_quat
from protocols.ensemble.messages import PoseShare

__all__ = ["RefinementPhase"]


class RefinementPhase:
    """Each module repeatedly replaces its own pose by the best one given its neighbours' (one message
    per neighbour per iteration); every few iterations the largest gradient entry is aggregated to the
    leader, which says whether to go on."""

    def __init__(self, agent):
        self.agent = agent
        agent.gather.leaders["grad"] = self.lead
        agent.gather.commands["grad"] = self.command

    def begin_refine(self, level: int) -> None:
        st = self.agent.levels.get(level)
        if st is None or st.leaf:
            return
        st.active, st.iteration, st.nbr_pose, st.previous = True, 0, {}, None

    def refine_send(self, level: int) -> None:
        a = self.agent
        st = a.levels.get(level)
        if st is None or not st.active:
            return
        pose = a.pose()
        if st.nbrs:
            a.share_rounds += 1
            a.shares_sent += len(st.nbrs)
        for j in st.nbrs:
            a.link.send(PoseShare, j, "refine", level=level, group=st.group, phase="refine",
                        iteration=st.iteration, pose=pose)

    def star(self, st) -> tuple[EnsembleProblem, np.ndarray, np.ndarray] | None:
        """The module and its neighbours whose poses it holds, as a small problem with its current poses."""
        a = self.agent
        nb = [j for j in st.nbrs if j in st.nbr_pose and j in a.z_in]
        if not nb:
            return None
        m, d = len(nb), a.config.dim
        ar = np.arange(1, m + 1)
        i = np.concatenate([np.zeros(m, dtype=np.int64), ar])
        j = np.concatenate([ar, np.zeros(m, dtype=np.int64)])
        z = np.concatenate([np.array([a.z_out[k] for k in nb]), np.array([a.z_in[k] for k in nb])])
        star = EnsembleProblem(d, m + 1, a.config.radius, i, j, z)
        pos = np.concatenate([a.position[None], np.array([st.nbr_pose[k][0] for k in nb])])
        rot = np.concatenate([a.rotation[None], np.array([st.nbr_pose[k][1] for k in nb])])
        return star, pos, rot

    def refine_update(self, level: int) -> None:
        """One local step: measure the own gradient, then move to the best pose given the neighbours."""
        a = self.agent
        st = a.levels.get(level)
        if st is None or not st.active:
            return
        made = self.star(st)
        st.iteration += 1
        if made is None:
            st.last_grad = 0.0
            return
        star, pos, rot = made
        cfg = a.config
        ori = matrix_to_angle(rot) if cfg.dim == 2 else matrix_to_quat(rot)
        g_pos, _ = gradient(star, pos, ori)
        st.last_grad = float(np.abs(g_pos[0]).max() / cfg.radius)
        # best own orientation for the current centres (closed-form Kabsch, eq. 1 per module)
        R_new = fit_orientations(star, pos)[0]
        m = star.n - 1
        rz_out = np.einsum("ab,mb->ma", R_new, star.z[:m])
        rz_in = np.einsum("mab,mb->ma", rot[1:], star.z[m:])
        # best own centre for the neighbours' poses: mean of c_j - R_i z_ij + R_j z_ji
        target = np.mean(pos[1:] - rz_out + rz_in, axis=0)
        a.rotation = R_new
        # damped local step with heavy-ball momentum (local: uses only the module's own history)
        prev = st.previous if st.previous is not None else a.position
        new = a.position + cfg.step * (target - a.position) + cfg.momentum * (a.position - prev)
        st.previous = a.position
        a.position = new

    def begin_grad(self, level: int) -> None:
        st = self.agent.levels.get(level)
        if st is None or not st.active:
            return
        self.agent.gather.begin(level, "grad", {"g": np.array([st.last_grad])})

    def lead(self, level: int, total: dict) -> None:
        """At the group leader: stop once the largest gradient entry is below the tolerance, or at the cap."""
        a = self.agent
        st = a.levels[level]
        cap = a.config.top_max_iter if level == 0 else a.config.level_max_iter
        gtol = a.config.top_gtol if level == 0 else a.config.hierarchy.level_refine.gtol
        stop = bool(total["g"][0] <= gtol or st.iteration >= cap)
        a.gather.command(level, "grad", {"stop": np.array([stop]), "g": total["g"]})

    def command(self, level: int, payload: dict) -> None:
        a = self.agent
        if bool(payload["stop"][0]):
            a.levels[level].active = False
        a.gather.disseminate(level, "grad", payload)

    def refining(self, level: int) -> bool:
        st = self.agent.levels.get(level)
        return st is not None and st.active
