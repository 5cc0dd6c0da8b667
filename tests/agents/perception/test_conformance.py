"""Every detector, identifier and tracker of agents.perception passes its conformance function."""

import importlib
import inspect
import pkgutil

import numpy as np
import pytest

import agents.perception
from agents.perception.conformance import detector_test, identifier_test, tracker_test
from agents.perception.detectors import DETECTORS, make_detector
from agents.perception.types import Circle


def _implementations(*methods: str) -> set[str]:
    """Names of the classes defined in agents.perception.* (not the protocols) with every one of ``methods``."""
    found = set()
    for info in pkgutil.iter_modules(agents.perception.__path__, "agents.perception."):
        module = importlib.import_module(info.name)
        for name, cls in inspect.getmembers(module, inspect.isclass):
            if getattr(cls, "_is_protocol", False):
                continue  # the protocols themselves
            if cls.__module__ == module.__name__ and all(callable(getattr(cls, m, None)) for m in methods):
                found.add(name)
    return found


def _onnx_detector(tmp_path):
    pytest.importorskip("onnx")
    from agents.perception.onnx_head import OnnxCircleDetector, OnnxHeadConfig
    from tests.agents.perception.test_perception_onnx import H, R, W, _model

    det = OnnxCircleDetector(_model(tmp_path / "head.onnx"), OnnxHeadConfig(input_size=(W, H), channels=1))
    return det, {"size": (W, H), "radius": R}


def _sphere_identifier():
    from agents.perception.sphere_tags import SphereTagIdentifier

    ident = SphereTagIdentifier(np.array([[400.0, 0, 160], [0, 400.0, 120], [0, 0, 1]]), 0.06)
    ident.set_view(np.eye(3))
    return ident, {"reads_flat_tags": False}


#: class name -> how to build one for its check (object, keyword arguments of the check)
DETECTOR_CLASSES = {"HoughCircleDetector": "hough", "RimCircleDetector": "rim",
                    "SymmetryCircleDetector": "symmetry", "LearnedCircleDetector": "learned",
                    "OnnxCircleDetector": None}
def _apriltag3_identifier():
    from agents.perception.apriltag3 import AprilTag3Identifier

    return AprilTag3Identifier(), {}


IDENTIFIERS = {
    "AprilTagIdentifier": lambda: (agents.perception.AprilTagIdentifier(), {}),
    "AprilTag3Identifier": _apriltag3_identifier,
    "SphereTagIdentifier": _sphere_identifier,
}
TRACKERS = {"CircleTracker": lambda: (agents.perception.CircleTracker(), {})}


def test_every_implementation_is_checked():
    """Each class with detect(), identify() or update()+reset() in agents.perception has a conformance case here."""
    assert _implementations("detect") == set(DETECTOR_CLASSES)
    assert _implementations("identify") == set(IDENTIFIERS)
    assert _implementations("update", "reset") == set(TRACKERS)
    assert set(DETECTORS) == {v for v in DETECTOR_CLASSES.values() if v}


#: detector name -> the images it is checked on, where they differ from detector_test's defaults: the learned
#: detector's networks see a downscale of a 4:3 frame (384 x 288) and were trained on spheres filling at most about
#: a fifth of its height, so a 30 px disc is checked in a 640 x 480 frame; its second stage is accurate to 2.5 px
#: on discs of another renderer (tests/agents/perception/test_perception_learned.py)
DETECTOR_CHECK = {"learned": {"size": (640, 480), "centre_tol": 2.5}}


@pytest.mark.parametrize("name", DETECTORS)
def test_named_detector_conforms(name):
    """Every detector of the registry passes detector_test."""
    detector_test(make_detector(name), **DETECTOR_CHECK.get(name, {}))


def test_onnx_detector_conforms(tmp_path):
    """The ONNX circle head (on a tiny test network) passes detector_test."""
    det, kwargs = _onnx_detector(tmp_path)
    detector_test(det, **kwargs)


@pytest.mark.parametrize("name", sorted(IDENTIFIERS))
def test_identifier_conforms(name):
    """Every identifier passes identifier_test."""
    ident, kwargs = IDENTIFIERS[name]()
    identifier_test(ident, **kwargs)


@pytest.mark.parametrize("name", sorted(TRACKERS))
def test_tracker_conforms(name):
    """Every tracker passes tracker_test."""
    tracker, kwargs = TRACKERS[name]()
    tracker_test(tracker, **kwargs)


def test_detector_test_names_a_missed_disc():
    """A detector that swaps u and v fails detector_test with a message saying it missed the disc."""
    class Swapped:
        def __init__(self):
            self.inner = make_detector("hough")

        def detect(self, image):
            return [Circle(c.v, c.u, c.r, c.score) for c in self.inner.detect(image)]

    with pytest.raises(AssertionError, match="missed the disc"):
        detector_test(Swapped())


def test_identifier_test_refuses_a_wrong_length():
    """An identifier that returns one entry whatever the circles fails identifier_test."""
    class OneRead:
        def identify(self, image, circles):
            return [None]

    with pytest.raises(AssertionError, match="empty list|one entry per circle|entries"):
        identifier_test(OneRead())


def test_tracker_test_refuses_forgotten_node_ids():
    """A tracker that drops node ids when tags are not read fails tracker_test."""
    from agents.perception.types import TrackedCircle

    class Forgetful:
        def __init__(self):
            self.inner = agents.perception.CircleTracker()

        def reset(self):
            self.inner.reset()

        def update(self, circles, reads, *, motion=None):
            return [TrackedCircle(t.circle, t.read, t.read.node if t.read else None, t.track)
                    for t in self.inner.update(circles, reads, motion=motion)]

    with pytest.raises(AssertionError, match="carry a track's node id"):
        tracker_test(Forgetful())
