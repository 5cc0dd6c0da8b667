"""A swarm robot's on-board agent: config + private state + message handlers (house style 9).

Each robot keeps, as Kanovsky §3 describes, an estimate of every other robot relative to itself
(itself at the origin), and reports what it knows to the swarm; following Kanovsky §5 it filters:
an EKF on its own motion and one EKF track per other robot (:mod:`decentral.filtering`). It sees
only its own sensors and its inbox, never ground truth.

One step ``k`` (time ``t_k``) has two radio phases, each a round of
:class:`protocols.consensus.RoundGather`:

A. *sense*: the robot broadcasts its odometry (:class:`OdometryReport`) and its identified
   detections (:class:`Tracks`); at the phase deadline it predicts every track with its own and the
   target's odometry (a lost odometry report becomes the target's unknown-motion covariance: an
   explicit failure, counted), updates tracks with its own detections, and with the detections of
   itself that peers shared (mutual observation: the only source of relative yaw for spheres; the
   first one initializes the yaw in closed form).
B. *share*: it broadcasts its tracks (:class:`PoseEstimates`); at the deadline it fuses peers'
   estimates by covariance intersection into tracks that no direct measurement updated this step,
   and creates tracks of robots it has never seen from them.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field, replace

import numpy as np
from scipy import stats

from decentral.filtering import (
    compose,
    compose_jacobians,
    covariance_intersection,
    invert,
    invert_jacobian,
    predict_pose,
    predict_relative,
    project_target,
    update_detection,
    yaw_from_mutual,
)
from decentral.geometry import backproject, wrap_angle
from decentral.observations import Detection, Odometry
from protocols.consensus import GatherResult, RoundGather
from protocols.messages import BROADCAST, Message, OdometryReport, PoseEstimates, Tracks
from protocols.transport import Delivery
from sims.simulation.swarm.config import SwarmConfig

__all__ = ["Track", "RobotStats", "SwarmRobot"]

#: tracks with a larger yaw variance [rad^2] are initialized from the next mutual detection
YAW_UNKNOWN_VAR = 0.3
#: above this yaw variance [rad^2] a mutual detection re-initializes the yaw instead of an EKF update
YAW_LINEAR_VAR = 0.15
#: yaw variance of a track whose yaw nobody has measured (uniform on the circle)
YAW_PRIOR_VAR = np.pi**2 / 3
#: tracks are shared only while their position std is below this [m]
SHARE_MAX_STD = 1.0
GATE = float(stats.chi2.ppf(0.999, 3))
#: steps of own motion repeated in each odometry report (a lost report is recovered from a later one)
ODOMETRY_HISTORY = 4


@dataclass
class Track:
    """The robot's belief about one other robot: pose in the robot's current frame and covariance."""

    mean: np.ndarray
    cov: np.ndarray
    last_direct: float
    source: str = "camera"
    applied: int = 0  # last round whose motion of the target has been applied

    @property
    def yaw_known(self) -> bool:
        return bool(self.cov[2, 2] < YAW_UNKNOWN_VAR)


@dataclass
class RobotStats:
    """Counters of what happened to this robot's inputs."""

    own_updates: int = 0
    mutual_updates: int = 0
    yaw_inits: int = 0
    gated: int = 0
    fused: int = 0
    created_from_peers: int = 0
    odometry_missing: int = 0
    deferred: int = 0
    reports_late: int = 0


class SwarmRobot:
    """One robot's agent.

    Parameters
    ----------
    name : str
        This robot (``"Ri"``); its node id is ``i``.
    config : SwarmConfig
        Shared swarm parameters (camera model, noise models): what the robot is told, not the truth.
    """

    def __init__(self, name: str, config: SwarmConfig):
        self.name = name
        self.config = config
        self.node = config.names.index(name)
        self.peers = tuple(n for n in config.names if n != name)
        cam = config.cam_in_root()
        self._cam_R, self._cam_p, self._K = cam.R, cam.p, config.K
        self.pose = np.zeros(3)  # own pose in the start frame (Kanovsky: itself at the origin at start)
        self.pose_cov = np.zeros((3, 3))
        self.tracks: dict[str, Track] = {}
        self.stats = RobotStats()
        self._odom_gather = RoundGather(name, self.peers, OdometryReport)
        self._tracks_gather = RoundGather(name, self.peers, Tracks)
        self._est_gather = RoundGather(name, self.peers, PoseEstimates)
        self._k = -1
        self._t = 0.0
        self._odometry: np.ndarray | None = None
        self._odometry_cov = np.zeros((3, 3))
        self._history: deque = deque(maxlen=ODOMETRY_HISTORY)
        self._detections: tuple[Detection, ...] = ()
        self._direct: set[str] = set()
        self.last_reports: dict[str, GatherResult] = {}

    # ------------------------------------------------------------------ phase A: sense
    def sense(self, k: int, t: float, odometry: Odometry | None, detections: tuple[Detection, ...]) -> list[Message]:
        """Take this step's own readings; return the phase-A messages to broadcast."""
        self._k, self._t = k, t
        self._detections = tuple(detections)
        out: list[Message] = []
        if k > 0:
            if odometry is not None:
                u = np.array([odometry.dp[0], odometry.dp[1], odometry.dtheta])
                self._odometry, self._odometry_cov = u, self.config.odometry_cov(u)
            else:
                self._odometry, self._odometry_cov = None, self.config.unknown_motion_cov()
            self._history.append((np.zeros(3) if self._odometry is None else self._odometry, self._odometry_cov))
            out.append(OdometryReport(sender=self.name, receiver=BROADCAST, round=k, t=t,
                                      motions=np.array([m for m, _ in self._history]),
                                      covariances=np.array([c for _, c in self._history])))
        ids = np.array([d.node for d in self._detections], dtype=np.int64)
        uvr = np.array([[d.u, d.v, d.r] for d in self._detections], dtype=float).reshape(-1, 3)
        out.append(Tracks(sender=self.name, receiver=BROADCAST, round=k, t=t, camera=f"{self.name}/cam0",
                          ids=ids, uvr=uvr))
        return out

    def receive(self, deliveries: list[Delivery]) -> None:
        """Route arrivals to the gathers by message kind."""
        for gather in (self._odom_gather, self._tracks_gather, self._est_gather):
            gather.receive(deliveries)

    def update(self) -> None:
        """Phase-A deadline: predict with odometry, update with own and mutual detections."""
        k, c = self._k, self.config
        odo = self._odom_gather.close(k)
        peer_tracks = self._tracks_gather.close(k)
        self.last_reports = {"odometry": odo, "tracks": peer_tracks}
        self._direct = set()
        if k > 0:
            u = self._odometry if self._odometry is not None else np.zeros(3)
            U = self._odometry_cov if self._odometry is not None else c.unknown_motion_cov()
            self.pose, self.pose_cov = predict_pose(self.pose, self.pose_cov, u, U)
            for name, tr in self.tracks.items():
                # own motion now; the target's motion when its report arrives (it composes on the
                # other side, so the order does not matter): s_k = -u_k + s_{k-1} + w_k
                tr.mean, tr.cov = predict_relative(tr.mean, tr.cov, u, U)
                self._advance(tr, odo.fresh.get(name))
        self.stats.reports_late += len(peer_tracks.late)
        self._own_updates()
        self._mutual_updates(peer_tracks)

    def _apply_target_motion(self, tr: Track, w: np.ndarray, W: np.ndarray) -> None:
        if tr.yaw_known:
            tr.mean, tr.cov = predict_relative(tr.mean, tr.cov, np.zeros(3), np.zeros((3, 3)), w, W)
        else:
            # the target's heading is unknown, so is the direction of its motion, and it keeps that
            # direction from step to step: its position std grows linearly by the step length (a
            # random walk would grow as sqrt and be overconfident)
            a = float(np.hypot(w[0], w[1]) + np.sqrt(W[0, 0] + W[1, 1]))
            sd = float(np.sqrt(np.linalg.eigvalsh(tr.cov[:2, :2])[-1]))
            tr.cov = tr.cov.copy()
            tr.cov[:2, :2] += (2 * sd * a + a * a) * np.eye(2)
            tr.cov[2, 2] += W[2, 2] + w[2] ** 2
        _forget_unknown_yaw(tr)

    def _advance(self, tr: Track, report: OdometryReport | None, *, force: bool = False, count: bool = True) -> None:
        """Apply the target's motions up to this round that are known, or can no longer be learned.

        A round missing from every report so far is waited for while a later report may still carry
        it (``ODOMETRY_HISTORY``); after that, or when ``force`` is set (the track is about to be
        measured or read), it becomes the unknown-motion covariance -- an explicit, counted failure.
        """
        k = self._k
        known = {}
        if report is not None:
            for row, (w, W) in enumerate(zip(report.motions, report.covariances)):
                known[report.first_round + row] = (w, W)
        for r in range(tr.applied + 1, k + 1):
            if r in known:
                self._apply_target_motion(tr, *known[r])
            elif force or r < k + 2 - ODOMETRY_HISTORY:
                self._apply_target_motion(tr, np.zeros(3), self.config.unknown_motion_cov())
                self.stats.odometry_missing += int(count)
            else:
                break
            tr.applied = r

    def _settle(self, tr: Track, *, count: bool = True) -> Track:
        """Bring a track fully to the current round (before a measurement or a read-out)."""
        if tr.applied < self._k:
            self._advance(tr, None, force=True, count=count)
        return tr

    def pending(self, name: str) -> bool:
        """Whether the track of ``name`` still waits for some of the target's motion."""
        tr = self.tracks.get(name)
        return tr is not None and tr.applied < self._k

    def _own_updates(self) -> None:
        c = self.config
        for d in self._detections:
            if d.node == self.node or not 0 <= d.node < c.n_robots:
                continue  # a stray or own tag
            name = c.names[d.node]
            uvr = np.array([d.u, d.v, d.r])
            tr = self.tracks.get(name)
            if tr is None:
                self.tracks[name] = self._new_track(uvr)
                self._direct.add(name)
                continue
            self._settle(tr)
            res = update_detection(tr.mean, tr.cov, uvr, c.pixel_cov, self._K, self._cam_R, self._cam_p,
                                   c.node_radius, gate=GATE)
            if res.accepted:
                tr.mean, tr.cov, tr.last_direct, tr.source = res.mean, res.cov, self._t, "camera"
                _forget_unknown_yaw(tr)
                self._direct.add(name)
                self.stats.own_updates += 1
            else:
                self.stats.gated += 1

    def _backproject(self, uvr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Position (2,) of a detected node in the camera's root frame and its covariance (2, 2)."""
        c = self.config
        pc = backproject(self._K, uvr[:1], uvr[1:2], uvr[2:3], c.node_radius)[0]  # Liu et al. 2024 eq. (1)
        xy = (self._cam_R @ pc + self._cam_p)[:2]
        _, H, _ = project_target(xy, self._K, self._cam_R, self._cam_p, c.node_radius)
        info = H.T @ np.linalg.solve(c.pixel_cov, H)
        return xy, np.linalg.inv(info)

    def _new_track(self, uvr: np.ndarray) -> Track:
        xy, P = self._backproject(uvr)
        cov = np.zeros((3, 3))
        cov[:2, :2] = P
        cov[2, 2] = YAW_PRIOR_VAR
        return Track(np.array([xy[0], xy[1], 0.0]), cov, self._t, applied=self._k)

    def _mutual_updates(self, peer_tracks: GatherResult) -> None:
        c = self.config
        for name, msg in peer_tracks.fresh.items():
            hits = np.flatnonzero(msg.ids == self.node)
            tr = self.tracks.get(name)
            if len(hits) == 0 or tr is None:
                continue
            uvr = np.asarray(msg.uvr[hits[0]], dtype=float)
            self._settle(tr)
            if tr.cov[2, 2] > YAW_LINEAR_VAR:
                # with a yaw this uncertain the measurement manifold curves away from its tangent:
                # an EKF update would be confidently wrong, so (re)initialize in closed form when
                # both views are of the same instant, and otherwise wait
                if name not in self._direct:
                    self.stats.deferred += 1
                    continue
                b, B = self._backproject(uvr)  # where the peer's camera put us, in the peer's frame
                t = tr.mean[:2]
                theta = yaw_from_mutual(t, b)
                # first-order variance of theta = atan2(-t_y, -t_x) - atan2(b_y, b_x)
                Jt = np.array([-t[1], t[0]]) / max(t @ t, 1e-12)
                Jb = -np.array([-b[1], b[0]]) / max(b @ b, 1e-12)
                var = float(Jt @ tr.cov[:2, :2] @ Jt + Jb @ B @ Jb)
                if var >= tr.cov[2, 2]:
                    self.stats.deferred += 1
                    continue  # the closed form would know less than the track already does
                tr.mean = np.array([t[0], t[1], theta])
                cross = tr.cov[:2, :2] @ Jt
                cov = tr.cov.copy()
                cov[2, 2] = var
                cov[:2, 2] = cov[2, :2] = cross
                tr.cov, tr.last_direct, tr.source = cov, self._t, "mutual"
                self._direct.add(name)
                self.stats.yaw_inits += 1
                continue
            res = update_detection(tr.mean, tr.cov, uvr, c.pixel_cov, self._K, self._cam_R, self._cam_p,
                                   c.node_radius, mutual=True, gate=GATE)
            if res.accepted:
                tr.mean, tr.cov, tr.last_direct, tr.source = res.mean, res.cov, self._t, "mutual"
                self._direct.add(name)
                self.stats.mutual_updates += 1
            else:
                self.stats.gated += 1

    # ------------------------------------------------------------------ phase B: share
    def share(self) -> list[Message]:
        """Phase-B message: this robot's tracks good enough to share, in its own frame."""
        subjects, poses, covs = [], [], []
        for name, tr in sorted(self.tracks.items()):
            # share only what this robot measured itself this step: passing on fused second-hand
            # estimates would feed peers' information back to them (a loop no covariance sees)
            if name in self._direct and np.sqrt(max(tr.cov[0, 0], tr.cov[1, 1])) < SHARE_MAX_STD:
                subjects.append(name)
                poses.append(tr.mean)
                covs.append(tr.cov)
        return [PoseEstimates(sender=self.name, receiver=BROADCAST, round=self._k, t=self._t,
                              subjects=tuple(subjects), poses=np.array(poses).reshape(-1, 3),
                              covariances=np.array(covs).reshape(-1, 3, 3))]

    def fuse(self) -> None:
        """Phase-B deadline: covariance-intersect peers' estimates into tracks not measured this step."""
        result = self._est_gather.close(self._k)
        self.last_reports["estimates"] = result
        for peer, msg in sorted(result.fresh.items()):
            for m, pose, C in zip(msg.subjects, msg.poses, msg.covariances):
                if m == self.name:
                    if peer not in self.tracks or peer in self._direct or C[2, 2] >= YAW_UNKNOWN_VAR:
                        continue  # inverting a pose of unknown yaw gives no usable position
                    if self.pending(peer):
                        continue  # its motion report is still to come: fusing now would settle it
                    J = invert_jacobian(pose)
                    self._fuse(peer, invert(pose), J @ C @ J.T)
                    continue
                via = self.tracks.get(peer)
                if via is None or not via.yaw_known or m in self._direct or m not in self.config.names:
                    continue
                if self.pending(peer) or self.pending(m):
                    continue
                Ja, Jb = compose_jacobians(via.mean, pose)
                self._fuse(m, compose(via.mean, pose), Ja @ via.cov @ Ja.T + Jb @ C @ Jb.T)

    def _fuse(self, name: str, est: np.ndarray, cov: np.ndarray) -> None:
        cov = 0.5 * (cov + cov.T) + 1e-12 * np.eye(3)
        incoming = Track(est.copy(), cov, -np.inf, "peer", applied=self._k)
        _forget_unknown_yaw(incoming)
        tr = self.tracks.get(name)
        if tr is None:
            if np.sqrt(max(cov[0, 0], cov[1, 1])) < SHARE_MAX_STD:
                self.tracks[name] = incoming
                self.stats.created_from_peers += 1
            return
        d = incoming.mean - tr.mean
        d[2] = wrap_angle(d[2])
        if float(d @ np.linalg.solve(tr.cov + incoming.cov, d)) > GATE:
            self.stats.gated += 1  # the two disagree beyond their spreads: one of them is wrong
            return
        mean, P, _ = covariance_intersection(tr.mean, tr.cov, incoming.mean, incoming.cov)
        tr.mean, tr.cov = mean, P
        _forget_unknown_yaw(tr)
        self.stats.fused += 1

    # ------------------------------------------------------------------ read-out
    def estimate(self, name: str) -> Track | None:
        """Current belief about robot ``name`` (a copy, brought to this round), or ``None``."""
        tr = self.tracks.get(name)
        if tr is None:
            return None
        return self._settle(replace(tr, mean=tr.mean.copy(), cov=tr.cov.copy()), count=False)

    def estimates(self) -> dict[str, Track]:
        """Current beliefs about every tracked robot (copies, brought to this round)."""
        return {name: self.estimate(name) for name in sorted(self.tracks)}


def _forget_unknown_yaw(tr: Track) -> None:
    """Keep a track whose yaw is not known honest: yaw uniform, uncorrelated with the position.

    An EKF linearized at a heading that is off by up to pi would otherwise draw yaw "information"
    from position updates through spurious correlations.
    """
    if tr.cov[2, 2] >= YAW_UNKNOWN_VAR:
        tr.mean[2] = 0.0
        tr.cov[2, :2] = tr.cov[:2, 2] = 0.0
        tr.cov[2, 2] = YAW_PRIOR_VAR
