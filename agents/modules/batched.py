"""One level's refinement (Funiak et al. 2008 §V-A, Algorithm 1 line 11) for all its modules at once.

The refinement phase is ~90 % of the messages of the distributed algorithm (one pose share per
neighbour per iteration, plus a gradient check every few iterations), so simulating it one message
object at a time dominates the run time. :class:`BatchedRefinement` runs exactly the per-module
handlers of :class:`agents.modules.agent.ModuleAgent` (``refine_send``, ``refine_update``,
``begin_grad`` and the convergecast / dissemination of the check), but in lockstep over arrays with
one row per module, SIMD style:

- row ``i`` holds module i's private state (centre, orientation, previous centre, iteration, last
  gradient) and the neighbour poses that were *delivered* to it; an update of row ``i`` reads only
  these, exactly like the per-module handler;
- every message is a copy handed to the network in one :meth:`protocols.network.SimulatedNetwork.send_many`
  call per round and kind, with its exact wire size, and only the copies that
  :meth:`~protocols.network.SimulatedNetwork.poll_many` returns are received;
- rounds are counted as the round clock of :mod:`sims.runners.ensemble_distributed` counts them.

On a lossy network (``ModuleConfig.reliable``) the pose shares are acknowledged and retransmitted
every ``retry_rounds`` rounds until acknowledged, exactly as the per-message path does it (same
copies per link and round, in the same per-link order: acknowledgements, then shares), so the link
streams draw the same losses; the gradient check then runs on the caller's per-message driver. On a
lossless network a copy that does not arrive in its round raises
:class:`decentral.errors.ProtocolError`. At the end the state is written back into the agents (pose,
per-level state, sequence numbers, messages sent per phase), so the later phases see what the
per-module path would have left.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from agents.modules.agent import ModuleAgent
from decentral.ensemble.rotation import project_to_rotation
from decentral.errors import ProtocolError
from protocols.ensemble.messages import Ack, Command, PoseShare, Report
from protocols.network import SimulatedNetwork

__all__ = ["BatchedRefinement"]


def _digits(ids: np.ndarray) -> np.ndarray:
    """Length of the decimal name of each non-negative module id."""
    out = np.ones(ids.shape, dtype=np.int64)
    k = ids.copy()
    while True:
        k //= 10
        more = k > 0
        if not more.any():
            return out
        out += more


def _size_base(message) -> int:
    """Wire size of ``message`` minus the lengths of its sender and receiver names (the only
    variable-length fields of the refinement messages: integers are fixed i64, floats f64)."""
    return message.size_bytes - len(message.sender) - len(message.receiver)


class BatchedRefinement:
    """The refinement of level ``level`` for the modules ``members``, run in lockstep.

    Parameters
    ----------
    agents : sequence of ModuleAgent
        All agents; agent ``k`` is module ``k`` and agent index ``k`` on the network.
    members : sequence of int
        Modules refining at this level (the runner's members: every module of a non-leaf group).
    level : int
        Hierarchy level.
    net : SimulatedNetwork
        The network the agents are attached to.
    check_every : int
        Iterations between two gradient checks (the runner's schedule).
    driver : object, optional
        Needed on a lossy network: the per-message round clock (``round`` attribute and
        ``phase(start, members)``) that runs the gradient checks.
    """

    def __init__(self, agents: Sequence[ModuleAgent], members: Sequence[int], level: int,
                 net: SimulatedNetwork, check_every: int, driver=None):
        self.agents, self.level, self.net, self.check_every = agents, level, net, int(check_every)
        self.driver = driver
        self.ids = np.asarray(sorted(int(k) for k in members), dtype=np.int64)
        ids, m = self.ids, self.ids.size
        first = agents[int(ids[0])].config
        d = self.d = first.dim
        self.radius = first.radius
        self.reliable, self.retry = bool(first.reliable), int(first.retry_rounds)
        if self.reliable and driver is None:
            raise ProtocolError("batched refinement on a lossy network needs the per-message driver")
        row_of = np.full(len(agents), -1, dtype=np.int64)
        row_of[ids] = np.arange(m)
        states = [agents[int(k)].levels[level] for k in ids]
        for k in ids:
            agents[int(k)].begin_refine(level)
        self.states = states
        self.group = np.array([st.group for st in states], dtype=np.int64)
        self.active = np.array([st.active for st in states], dtype=bool)
        self.iteration = np.array([st.iteration for st in states], dtype=np.int64)
        self.last_grad = np.array([st.last_grad for st in states], dtype=float)
        self.pos = np.array([agents[int(k)].position for k in ids], dtype=float).reshape(m, d)
        self.rot = np.array([agents[int(k)].rotation for k in ids], dtype=float).reshape(m, d, d)
        self.prev = self.pos.copy()
        self.moved = np.zeros(m, dtype=bool)
        cfgs = [agents[int(k)].config for k in ids]
        self.step = np.array([c.step for c in cfgs])
        self.momentum = np.array([c.momentum for c in cfgs])
        self.cap = np.array([c.top_max_iter if level == 0 else c.level_max_iter for c in cfgs])
        self.gtol = np.array([c.top_gtol if level == 0 else c.hierarchy.level_refine.gtol for c in cfgs])

        # receive side: one slot per (receiver, neighbour) the per-module _star would use, in its order
        slot_row, slot_nb, z_out, z_in, slot_key = [], [], [], [], {}
        for r, (k, st) in enumerate(zip(ids.tolist(), states)):
            a = agents[k]
            for j in st.nbrs:
                if j in a.z_in and row_of[j] >= 0:
                    slot_key[(r, int(row_of[j]))] = len(slot_row)
                    slot_row.append(r)
                    slot_nb.append(int(row_of[j]))
                    z_out.append(a.z_out[j])
                    z_in.append(a.z_in[j])
        self.slot_row = np.array(slot_row, dtype=np.int64)
        self.slot_nb = np.array(slot_nb, dtype=np.int64)
        self.z_out = np.array(z_out, dtype=float).reshape(-1, d)
        self.z_in = np.array(z_in, dtype=float).reshape(-1, d)
        self.have = np.zeros(self.slot_row.size, dtype=bool)
        self.nb_pos = np.zeros((self.slot_row.size, d))
        self.nb_rot = np.zeros((self.slot_row.size, d, d))

        # send side: every share of refine_send (to each neighbour, counted whether or not it is used)
        send_row, send_to, send_slot = [], [], []
        for r, st in enumerate(states):
            for j in st.nbrs:
                send_row.append(r)
                send_to.append(int(j))
                rj = int(row_of[j])
                ok = rj >= 0 and states[rj].group == states[r].group
                send_slot.append(slot_key.get((rj, r), -1) if ok else -1)
        self.send_row = np.array(send_row, dtype=np.int64)
        self.send_to = np.array(send_to, dtype=np.int64)
        self.send_slot = np.array(send_slot, dtype=np.int64)

        # group trees (parent row, depth, height) for the gradient checks
        parent_id = np.array([st.parent for st in states], dtype=np.int64)
        self.parent = np.where(parent_id >= 0, row_of[np.maximum(parent_id, 0)], -1)
        if np.any((parent_id >= 0) & (self.parent < 0)):
            raise ProtocolError(f"level {level}: a tree parent is not refining at this level")
        self.depth, self.height, self.root = self._tree()

        # wire sizes: a fixed part plus the lengths of the sender and receiver names
        self.digits = _digits(np.arange(len(agents), dtype=np.int64))
        pose0 = np.zeros(d + d * d)
        self.size_pose = _size_base(PoseShare(sender="0", receiver="0", round=0, level=level, group=0,
                                              phase="refine", iteration=0, pose=pose0))
        self.size_report = _size_base(Report(sender="0", receiver="0", round=0, level=level, group=0,
                                             phase="grad", payload={"g": np.array([0.0])}))
        self.size_command = _size_base(Command(sender="0", receiver="0", round=0, level=level, group=0, phase="grad",
                                               payload={"stop": np.array([False]), "g": np.array([0.0])}))
        self.size_ack = _size_base(Ack(sender="0", receiver="0", round=0, seq=0, phase="refine"))
        self.sent = np.zeros(len(agents), dtype=np.int64)  # by module id (acknowledgers need not be members)
        self.seq = np.array([agents[int(k)]._seq for k in ids], dtype=np.int64)
        self.share_rounds = np.zeros(m, dtype=np.int64)
        self.shares_sent = np.zeros(m, dtype=np.int64)

    # ------------------------------------------------------------------ public
    def run(self, round_: int, progress=None) -> tuple[int, int]:
        """Iterate until every group's leader says stop; return (iterations, last round used).

        ``progress(iterations, refining)``, when given, is called after each convergence check with
        the iterations so far and the number of modules still refining.
        """
        self.round = int(round_)
        it = 0
        while self.active.any():
            live = self.active.copy()
            if self.reliable:
                self._share_reliable(live)
            else:
                self._share(live)
            self._update(live)
            it += 1
            if it % self.check_every == 0:
                if self.reliable:
                    self._check_per_message(live)
                else:
                    self._check(live)
                if progress is not None:
                    progress(it, int(self.active.sum()))
        self._write_back()
        return it, self.round

    # ------------------------------------------------------------------ one iteration
    def _send(self, kind: str, rows: np.ndarray, to_ids: np.ndarray, base: int) -> int:
        """Send one copy per (rows[k] -> module to_ids[k]) this round; return how many were sent."""
        self._send_ids(kind, self.ids[rows], to_ids, base)
        return rows.size

    def _send_ids(self, kind: str, ids: np.ndarray, to_ids: np.ndarray, base: int) -> int:
        """Send one copy per (module ids[k] -> module to_ids[k]) this round; return the batch id."""
        batch = self.net.send_many(kind, ids, to_ids, base + self.digits[ids] + self.digits[to_ids], float(self.round))
        np.add.at(self.sent, ids, 1)
        return batch

    def _deliver(self, expected: int):
        got = self.net.poll_many(float(self.round))
        if len(got) != expected:
            raise ProtocolError(f"batched refinement: {expected - len(got)} copies did not arrive in round "
                                f"{self.round}; the batched path needs a lossless network")
        return got

    def _share(self, live: np.ndarray) -> None:
        """refine_send on every live module, and the receive half (store the delivered poses)."""
        sel = np.flatnonzero(live[self.send_row])
        self.round += 1
        if sel.size == 0:  # nobody sends: the phase is one silent round
            return
        rows = self.send_row[sel]
        self.share_rounds[np.unique(rows)] += 1
        self.shares_sent += np.bincount(rows, minlength=self.ids.size)
        pos_now, rot_now = self.pos.copy(), self.rot.copy()
        self._send(PoseShare.KIND, rows, self.send_to[sel], self.size_pose)
        got = self._deliver(sel.size)
        self._store(sel, got.index, pos_now, rot_now)
        self.round += 1  # the receivers' round, in which nothing more is sent

    def _store(self, sel: np.ndarray, index: np.ndarray, pos_now: np.ndarray, rot_now: np.ndarray) -> None:
        """Receive half of the delivered shares ``sel[index]``: keep the pose where the receiver uses it."""
        slot = self.send_slot[sel[index]]
        src = self.send_row[sel[index]]
        ok = slot >= 0
        self.nb_pos[slot[ok]] = pos_now[src[ok]]
        self.nb_rot[slot[ok]] = rot_now[src[ok]]
        self.have[slot[ok]] = True

    def _share_reliable(self, live: np.ndarray) -> None:
        """refine_send with acknowledgements (lossy network), round by round as the per-message path:
        every delivered share is acknowledged the next round, and a share not acknowledged
        ``retry_rounds`` rounds after its last copy is sent again, until none is outstanding."""
        sel = np.flatnonzero(live[self.send_row])
        if sel.size == 0:
            self.round += 1
            return
        rows = self.send_row[sel]
        self.share_rounds[np.unique(rows)] += 1
        self.shares_sent += np.bincount(rows, minlength=self.ids.size)
        self.seq += np.bincount(rows, minlength=self.ids.size)  # one sequence number per share
        pos_now, rot_now = self.pos.copy(), self.rot.copy()
        src_ids, dst_ids = self.ids[rows], self.send_to[sel]
        pending = np.ones(sel.size, dtype=bool)
        last_sent = np.zeros(sel.size, dtype=np.int64)
        ack_for = np.zeros(0, dtype=np.int64)  # share copy each acknowledgement due this round answers
        first = True
        for _ in range(self.driver.max_rounds):
            self.round += 1
            # per link, the outbox order of the per-message path: acknowledgements, then (re)transmissions
            ack_batch = self._send_ids(Ack.KIND, dst_ids[ack_for], src_ids[ack_for], self.size_ack) \
                if ack_for.size else -1
            due = pending if first else pending & (self.round - last_sent >= self.retry)
            first = False
            share_rows = np.flatnonzero(due)
            share_batch = self._send_ids(PoseShare.KIND, src_ids[share_rows], dst_ids[share_rows], self.size_pose) \
                if share_rows.size else -1
            last_sent[share_rows] = self.round
            got = self.net.poll_many(float(self.round))
            acked = ack_for[got.index[got.batch == ack_batch]]
            pending[acked] = False
            delivered = share_rows[got.index[got.batch == share_batch]]
            self._store(sel, delivered, pos_now, rot_now)
            ack_for = delivered
            if len(got) == 0 and not pending.any():
                return
        raise ProtocolError(f"a refinement share exchange did not settle within {self.driver.max_rounds} rounds")

    def _check_per_message(self, live: np.ndarray) -> None:
        """The gradient check on the per-message path (lossy network): hand the agents the state it
        reads, run it on the driver's round clock, and read back who stops."""
        rows = np.flatnonzero(live)
        for r in rows.tolist():
            st = self.states[r]
            st.last_grad, st.iteration = float(self.last_grad[r]), int(self.iteration[r])
            self.agents[int(self.ids[r])]._seq = int(self.seq[r])
        self.driver.round = self.round
        level = self.level
        self.driver.phase(lambda a: a.begin_grad(level), self.ids[rows].tolist())
        self.round = self.driver.round
        for r in rows.tolist():
            self.active[r] = self.states[r].active
            self.seq[r] = self.agents[int(self.ids[r])]._seq

    def _update(self, live: np.ndarray) -> None:
        """refine_update on every live module (Funiak et al. 2008 eq. 1-2 restricted to its star)."""
        m, d = self.ids.size, self.d
        self.iteration[live] += 1
        use = np.flatnonzero(self.have & live[self.slot_row])
        sr = self.slot_row[use]
        cnt = np.bincount(sr, minlength=m)
        alone = live & (cnt == 0)
        self.last_grad[alone] = 0.0
        rows = np.flatnonzero(live & (cnt > 0))
        if rows.size == 0:
            return
        ci, Ri = self.pos[sr], self.rot[sr]
        cj, Rj = self.nb_pos[use], self.nb_rot[use]
        zo, zi = self.z_out[use], self.z_in[use]
        # gradient of the own centre: r_out = R_i z_ij - (c_j - c_i)/2, r_in = R_j z_ji - (c_i - c_j)/2
        r_out = np.einsum("eab,eb->ea", Ri, zo) - 0.5 * (cj - ci)
        r_in = np.einsum("eab,eb->ea", Rj, zi) - 0.5 * (ci - cj)
        g = np.stack([0.5 * (np.bincount(sr, r_out[:, a], m) - np.bincount(sr, r_in[:, a], m)) for a in range(d)], 1)
        self.last_grad[rows] = np.abs(g[rows]).max(1) / self.radius
        # best own orientation for the current centres: Kabsch on sum_j (c_j - c_i)/2 z_ij^T
        dvec = 0.5 * (cj - ci)
        M = np.zeros((m, d, d))
        np.add.at(M, sr, dvec[:, :, None] * zo[:, None, :])
        R_new = np.zeros((m, d, d))
        R_new[rows] = project_to_rotation(M[rows])
        # best own centre for the neighbours' poses: mean of c_j - R_i z_ij + R_j z_ji
        rz_out = np.einsum("eab,eb->ea", R_new[sr], zo)
        rz_in = np.einsum("eab,eb->ea", Rj, zi)
        term = cj - rz_out + rz_in
        target = np.stack([np.bincount(sr, term[:, a], m) for a in range(d)], 1)[rows] / cnt[rows, None]
        x = self.pos[rows]
        prev = self.prev[rows]
        new = x + self.step[rows, None] * (target - x) + self.momentum[rows, None] * (x - prev)
        self.prev[rows] = x
        self.pos[rows] = new
        self.rot[rows] = R_new[rows]
        self.moved[rows] = True

    def _check(self, live: np.ndarray) -> None:
        """begin_grad: convergecast of the largest gradient entry to each group leader, which
        disseminates stop / go down the tree (the rounds as the per-message path takes them)."""
        m = self.ids.size
        rows = np.flatnonzero(live)
        has_parent = live & (self.parent >= 0)
        gsub = np.where(live, self.last_grad, -np.inf)
        # reports: a module of subtree height h reports in round h + 1 of the phase
        report_round = np.where(has_parent, self.height + 1, 0)
        # the leader of a group of height H decides in round H; depth-d modules forward in H + d + 1
        H = self.height[self.root]
        n_children = np.bincount(self.parent[has_parent], minlength=m)
        command_round = np.where(live & (n_children > 0), H + self.depth + 1, 0)
        last = int(max(report_round.max(initial=0), command_round.max(initial=0)))
        start = self.round
        for k in range(1, last + 1):
            self.round = start + k
            sent = 0
            up = np.flatnonzero(report_round == k)
            if up.size:
                np.maximum.at(gsub, self.parent[up], gsub[up])
                sent += self._send(Report.KIND, up, self.ids[self.parent[up]], self.size_report)
            down = np.flatnonzero(has_parent & (command_round[np.maximum(self.parent, 0)] == k))
            if down.size:
                sent += self._send(Command.KIND, self.parent[down], self.ids[down], self.size_command)
            self._deliver(sent)
        self.round = start + last + 1
        # the leaders' decisions (the value every member receives with the command)
        lead = self.root[rows]
        stop = (gsub[lead] <= self.gtol[lead]) | (self.iteration[lead] >= self.cap[lead])
        self.active[rows[stop]] = False

    # ------------------------------------------------------------------ tree and write-back
    def _tree(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Depth, subtree height and root row of every row, from the parent pointers."""
        m = self.ids.size
        parent = self.parent
        # walk every row up to its root in lockstep: O(tree depth) vector passes
        depth = (parent >= 0).astype(np.int64)
        cur = np.where(parent >= 0, parent, np.arange(m))
        while True:
            moving = parent[cur] >= 0
            if not moving.any():
                break
            depth += moving
            cur = np.where(moving, parent[cur], cur)
        root = cur
        height = np.zeros(m, dtype=np.int64)
        order = np.argsort(-depth, kind="stable")
        for r in order.tolist():
            p = parent[r]
            if p >= 0 and height[p] < height[r] + 1:
                height[p] = height[r] + 1
        return depth, height, root

    def _write_back(self) -> None:
        agents, d = self.agents, self.d
        for r, (k, st) in enumerate(zip(self.ids.tolist(), self.states)):
            a = agents[k]
            a.position = self.pos[r].copy()
            a.rotation = self.rot[r].copy()
            a._seq = int(self.seq[r])
            a.share_rounds += int(self.share_rounds[r])
            a.shares_sent += int(self.shares_sent[r])
            st.iteration = int(self.iteration[r])
            st.last_grad = float(self.last_grad[r])
            st.active = bool(self.active[r])
            if self.moved[r]:
                st.previous = self.prev[r].copy()
        for k in np.flatnonzero(self.sent).tolist():
            agents[k].sent["refinement"] += int(self.sent[k])
        for s in np.flatnonzero(self.have).tolist():
            st = self.states[int(self.slot_row[s])]
            st.nbr_pose[int(self.ids[self.slot_nb[s]])] = (self.nb_pos[s].copy(), self.nb_rot[s].reshape(d, d).copy())
