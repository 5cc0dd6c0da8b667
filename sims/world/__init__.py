"""The geometry-only world: assemblies, their motion, cameras, sensors and ground truth."""

from sims.world.camera import CameraSpec, default_K
from sims.world.sensors import SensorNoise
from sims.world.shapes import NODE_RADIUS, Shape, library_shape
from sims.world.truth import Truth, read_truth, write_truth
from sims.world.world import AssemblyTrack, CameraRig, World

__all__ = [
    "AssemblyTrack",
    "CameraRig",
    "CameraSpec",
    "NODE_RADIUS",
    "SensorNoise",
    "Shape",
    "Truth",
    "World",
    "default_K",
    "library_shape",
    "read_truth",
    "write_truth",
]
