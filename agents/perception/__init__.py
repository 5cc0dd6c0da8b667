"""An observer's perception front end (Liu et al. 2024 §III): node circles, AprilTag ids, tracking.

Each stage sits behind a small protocol (:class:`CircleDetector`, :class:`Identifier`,
:class:`Tracker`) so it can be swapped; :class:`Perception` chains them. OpenCV is used here (and in
``sims``) only.
"""

from agents.perception.apriltag import AprilTagConfig, AprilTagIdentifier
from agents.perception.detectors import DETECTORS, make_detector
from agents.perception.hough import HoughCircleDetector, HoughConfig
from agents.perception.motion import FlowRegistration, odometry_homography
from agents.perception.onnx_head import OnnxCircleDetector, OnnxHeadConfig
from agents.perception.pipeline import FrameResult, Perception, perceive_frames
from agents.perception.refine import RefineConfig
from agents.perception.rim import RimCircleDetector, RimConfig
from agents.perception.symmetry_detector import SymmetryCircleDetector, SymmetryConfig
from agents.perception.tracking import CircleTracker, TrackerConfig
from agents.perception.types import Circle, CircleDetector, Identifier, TagRead, TrackedCircle, Tracker

__all__ = [
    "AprilTagConfig",
    "AprilTagIdentifier",
    "Circle",
    "CircleDetector",
    "CircleTracker",
    "DETECTORS",
    "FlowRegistration",
    "FrameResult",
    "HoughCircleDetector",
    "HoughConfig",
    "Identifier",
    "OnnxCircleDetector",
    "OnnxHeadConfig",
    "Perception",
    "RefineConfig",
    "RimCircleDetector",
    "RimConfig",
    "SymmetryCircleDetector",
    "SymmetryConfig",
    "TagRead",
    "TrackedCircle",
    "Tracker",
    "TrackerConfig",
    "make_detector",
    "odometry_homography",
    "perceive_frames",
]
