"""Parameters of Kanovsky's camera swarm: robots, cameras, sensor noise and the radio.

Kanovsky §3.1: each robot sees others inside a cone (``max_angle`` from the camera's centre line,
``max_distance`` away), identifies them by a tag, and reports to the swarm over a network. Its §5
asks for measurement noise and a filter on each robot's own motion; both are parameters here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

import numpy as np

from decentral.errors import InputError
from decentral.observations import Camera, Pose
from protocols.network import LinkConfig

__all__ = ["SwarmConfig", "CAM_LOOKS_ALONG_X"]

#: camera-in-strut rotation of an OpenCV camera looking along the strut's +x (the example of docs/formats.md)
CAM_LOOKS_ALONG_X = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


@dataclass(frozen=True)
class SwarmConfig:
    """Everything that defines a swarm run except the seed.

    Attributes
    ----------
    n_robots : int
        Number of one-node robots, named ``R0 .. R{n-1}``; robot ``Ri`` carries node id ``i``.
    arena : float
        Side [m] of the square arena ``[0, arena]^2`` the robots stay in.
    dt : float
        Step [s] (camera frame and radio round).
    node_radius : float
        Radius r_0 [m] of each robot's spherical node.
    max_angle_deg : float
        Half-angle of the camera's field-of-view cone [deg] (Kanovsky ``max_angle``).
    max_distance : float
        Farthest detection [m] (Kanovsky ``max_distance``).
    image_width, image_height : int
        Image size [px]; the focal length follows from ``max_angle_deg``.
    min_radius_px : float
        Smallest circle a detector finds [px].
    pixel_sigma, radius_sigma : float
        Detection noise std of the circle centre and radius [px].
    dropout : float
        Probability that a visible robot's tag is not read in a frame.
    odom_frac, odom_floor : float
        Odometry translation noise std per component: ``odom_frac * |dp| + odom_floor`` [m].
    yaw_frac, yaw_floor : float
        Odometry yaw noise std: ``yaw_frac * |dtheta| + yaw_floor`` [rad].
    max_speed, max_yaw_rate : float
        Limits of the unicycle commands [m/s], [rad/s].
    link : LinkConfig
        Radio behaviour of every link.
    deadline : float
        Fraction of ``dt`` after which a robot stops waiting for the step's reports.
    """

    n_robots: int = 6
    arena: float = 5.0
    dt: float = 0.2
    node_radius: float = 0.06
    max_angle_deg: float = 50.0
    max_distance: float = 3.5
    image_width: int = 640
    image_height: int = 480
    min_radius_px: float = 2.0
    pixel_sigma: float = 0.7
    radius_sigma: float = 0.4
    dropout: float = 0.05
    odom_frac: float = 0.05
    odom_floor: float = 0.001
    yaw_frac: float = 0.05
    yaw_floor: float = 0.004
    max_speed: float = 0.3
    max_yaw_rate: float = 1.2
    link: LinkConfig = field(default_factory=lambda: LinkConfig(latency=0.005, jitter=0.01))
    deadline: float = 0.4

    def __post_init__(self) -> None:
        if not (isinstance(self.n_robots, int) and 1 <= self.n_robots <= 1000):
            raise InputError(f"must be an integer in [1, 1000], got {self.n_robots!r}", field="n_robots")
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name in ("n_robots", "link"):
                continue
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise InputError(f"must be a finite non-negative number, got {v!r}", field=f.name)
        for name in ("arena", "dt", "node_radius", "max_distance", "image_width", "image_height", "max_speed"):
            if getattr(self, name) <= 0:
                raise InputError("must be positive", field=name)
        if not 0 < self.max_angle_deg < 89:
            raise InputError("must be in (0, 89) degrees", field="max_angle_deg")
        if self.dropout > 1:
            raise InputError("is a probability", field="dropout")
        if not 0 < self.deadline < 0.5:
            raise InputError("must be in (0, 0.5): two report phases share one step", field="deadline")
        if not isinstance(self.link, LinkConfig):
            raise InputError("must be a LinkConfig", field="link")

    @property
    def names(self) -> tuple[str, ...]:
        """Robot names in order."""
        return tuple(f"R{i}" for i in range(self.n_robots))

    @property
    def K(self) -> np.ndarray:
        """Pinhole intrinsics (3, 3) whose horizontal half field of view is ``max_angle_deg``."""
        f = (self.image_width / 2.0) / math.tan(math.radians(self.max_angle_deg))
        return np.array([[f, 0.0, self.image_width / 2.0], [0.0, f, self.image_height / 2.0], [0.0, 0.0, 1.0]])

    @property
    def strut_in_root(self) -> Pose:
        """The camera strut sits on the node's surface, facing the robot's heading (+x)."""
        return Pose(np.eye(3), np.array([self.node_radius, 0.0, 0.0]))

    @property
    def cam_in_strut(self) -> Pose:
        """Camera 2 cm ahead of and 3 cm above the strut origin, looking along +x."""
        return Pose(CAM_LOOKS_ALONG_X.copy(), np.array([0.02, 0.0, 0.03]))

    def camera(self, name: str) -> Camera:
        """The log declaration of robot ``name``'s camera ``cam0``."""
        return Camera(name, "cam0", self.K, self.strut_in_root, self.cam_in_strut)

    def cam_in_root(self) -> Pose:
        """Pose of the camera in the robot's root frame."""
        return self.strut_in_root.compose(self.cam_in_strut)

    def odometry_cov(self, motion: np.ndarray) -> np.ndarray:
        """Covariance (3, 3) of the odometry noise for a true step ``motion`` (dx, dy, dtheta)."""
        travel = float(np.hypot(motion[0], motion[1]))
        sp = self.odom_frac * travel + self.odom_floor
        st = self.yaw_frac * abs(float(motion[2])) + self.yaw_floor
        return np.diag([sp**2, sp**2, st**2])

    def unknown_motion_cov(self) -> np.ndarray:
        """Covariance (3, 3) of a robot's motion over one step when its odometry report is lost."""
        s = self.max_speed * self.dt
        return np.diag([s**2, (0.5 * s) ** 2, (self.max_yaw_rate * self.dt) ** 2])

    @property
    def pixel_cov(self) -> np.ndarray:
        """Covariance (3, 3) of a detection's (u, v, r) [px^2]."""
        return np.diag([self.pixel_sigma**2, self.pixel_sigma**2, self.radius_sigma**2])
