"""The kinds a swarm robot shares with its peers (Kanovsky): its tracks, its pose estimates of others, its odometry."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from decentral.errors import ProtocolError
from protocols.fields import as_array, finite_array, finite_float, set_field
from protocols.message_base import Message, register

__all__ = ["OdometryReport", "PoseEstimates", "Tracks"]


@register
@dataclass(frozen=True, slots=True, eq=False, kw_only=True)
class Tracks(Message):
    """One camera frame's identified node detections, shared with other agents.

    Attributes
    ----------
    t : float
        Time of the frame (s).
    camera : str
        Camera key ``"assembly/camera"`` as in ``decentral.log/1``.
    ids : ndarray, shape (n,), int64
        Node ids (unique within the frame).
    uvr : ndarray, shape (n, 3), float64
        Image centre ``(u, v)`` and radius ``r`` of each detection, pixels.
    """

    KIND: ClassVar[str] = "tracks"

    t: float
    camera: str
    ids: np.ndarray
    uvr: np.ndarray

    def __post_init__(self) -> None:
        Message.__post_init__(self)
        set_field(self, "t", finite_float(self.t, "t"))
        if not isinstance(self.camera, str) or "/" not in self.camera:
            raise ProtocolError("field 'camera': must be a key 'assembly/camera'")
        ids = as_array(self.ids, "ids", dtype=np.int64, ndim=1)
        set_field(self, "ids", ids)
        set_field(self, "uvr", finite_array(self.uvr, "uvr", shape=(ids.shape[0], 3)))
        if len(np.unique(ids)) != len(ids):
            raise ProtocolError("field 'ids': duplicate node ids in one frame")


@register
@dataclass(frozen=True, slots=True, eq=False, kw_only=True)
class PoseEstimates(Message):
    """The sender's planar estimates of other agents relative to itself (Kanovsky §3).

    Attributes
    ----------
    t : float
        Time the estimates refer to (s).
    subjects : tuple of str, length n
        Names of the estimated agents (unique).
    poses : ndarray, shape (n, 3), float64
        ``(x, y, theta)`` of each subject's frame in the sender's frame at ``t`` (m, m, rad).
    covariances : ndarray, shape (n, 3, 3), float64
        Covariance of each pose, in the same order.
    """

    KIND: ClassVar[str] = "pose_estimates"

    t: float
    subjects: tuple[str, ...]
    poses: np.ndarray
    covariances: np.ndarray

    def __post_init__(self) -> None:
        Message.__post_init__(self)
        set_field(self, "t", finite_float(self.t, "t"))
        subjects = self.subjects
        if not isinstance(subjects, tuple) or not all(isinstance(s, str) and s for s in subjects):
            raise ProtocolError("field 'subjects': must be a tuple of names")
        if len(set(subjects)) != len(subjects):
            raise ProtocolError("field 'subjects': duplicate names")
        n = len(subjects)
        set_field(self, "poses", finite_array(self.poses, "poses", shape=(n, 3)))
        set_field(self, "covariances", finite_array(self.covariances, "covariances", shape=(n, 3, 3)))


@register
@dataclass(frozen=True, slots=True, eq=False, kw_only=True)
class OdometryReport(Message):
    """The sender's own planar motion over its last ``L`` steps, so peers can predict its pose.

    Repeating recent steps lets a receiver that lost a report recover the motion from the next one.

    Attributes
    ----------
    t : float
        Time at the end of step ``round`` (s).
    motions : ndarray, shape (L, 3), float64
        Row ``l`` is ``(dx, dy, dtheta)`` of step ``round - L + 1 + l``: the sender's root at the end
        of that step in its root frame at the previous step (Liu et al. 2024 eq. (6)).
    covariances : ndarray, shape (L, 3, 3), float64
        Noise covariance of each row of ``motions``.
    """

    KIND: ClassVar[str] = "odometry"

    t: float
    motions: np.ndarray
    covariances: np.ndarray

    def __post_init__(self) -> None:
        Message.__post_init__(self)
        set_field(self, "t", finite_float(self.t, "t"))
        motions = finite_array(self.motions, "motions", ndim=2)
        if motions.shape[1] != 3 or motions.shape[0] < 1:
            raise ProtocolError(f"field 'motions': expected shape (L >= 1, 3), got {motions.shape}")
        set_field(self, "motions", motions)
        set_field(self, "covariances", finite_array(self.covariances, "covariances", shape=(motions.shape[0], 3, 3)))

    @property
    def first_round(self) -> int:
        """Round of the first row of ``motions``."""
        return self.round - self.motions.shape[0] + 1
