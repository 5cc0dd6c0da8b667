"""The geometry-only world: assemblies, their motion, cameras, sensors and ground truth."""

from sims.simulation.world.camera import CameraSpec, default_K
from sims.simulation.world.sensors import SensorNoise
from sims.simulation.world.shapes import NODE_RADIUS, Shape, library_shape
from sims.simulation.world.truth import Truth, read_truth, write_truth
from sims.simulation.world.world import AssemblyTrack, CameraRig, World

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
