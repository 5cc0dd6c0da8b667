"""The circle detectors by name: ``"learned"`` (the default), ``"hough"``, ``"rim"`` and ``"symmetry"``.

``"learned"`` is :class:`~agents.perception.learned.LearnedCircleDetector`: two small networks
shipped with the package (proposals, then a second stage per circle), run by onnxruntime (OpenCV's
``dnn`` where it is missing); better than hough on every measured set: held-out varied floors,
mottled floors, the rendered ``table1`` and ``multi`` frames and Table I end to end, at about the same
frames a second for the whole front end (the figures of the shipped networks: docs/perception.md,
"Learned detector", and the model card ``agents/perception/models/circles.md``).
``"hough"`` is :class:`~agents.perception.hough.HoughCircleDetector` (the default before): no
network, about 15-30 ms of CPU per 1024 x 768 frame, good on the rendered frames, poor on floors it
was not tuned on. ``"rim"`` is
:class:`~agents.perception.rim.RimCircleDetector`: it reports the sphere's outline where the default
fits the tag (large spheres coloured like the floor, a tag near the limb, partly hidden spheres), at
about five times the cost. ``"symmetry"`` is :class:`~agents.perception.symmetry_detector.SymmetryCircleDetector`:
colour-edge radial-symmetry candidates verified on the rim; the best recall on the varied frames at
about three times hough's cost, but worse than hough on the rendered ``table1`` frames.
docs/perception.md gives the measured figures.
"""

from __future__ import annotations

import numpy as np

from agents.perception.hough import HoughCircleDetector, HoughConfig
from agents.perception.rim import RimCircleDetector, RimConfig
from agents.perception.symmetry_detector import SymmetryCircleDetector, SymmetryConfig
from agents.perception.types import CircleDetector

__all__ = ["DEFAULT_DETECTOR", "DETECTORS", "LOG_MIN_SCORE", "make_detector"]

DETECTORS = ("hough", "rim", "symmetry", "learned")
#: the detector used where none is named (``perceive``, :class:`~agents.perception.pipeline.Perception`,
#: the perception runs and experiments)
DEFAULT_DETECTOR = "learned"
#: per detector, the score below which a detection stays out of a filled log (``perceive --log-out``, the
#: experiments, ``build-log``): hough's, rim's and symmetry's score is the rim's support (0.5: partly hidden
#: rims and off-centre fits stay out); the learned detector's is its heatmap peak, and its circles have
#: passed its own gates already (a peak of at least 0.3, a settled second stage), so none is dropped (at
#: 0.5 Fig. 4's target was placed in 5 of 80 steps instead of 47)
LOG_MIN_SCORE = {"hough": 0.5, "rim": 0.5, "symmetry": 0.5, "learned": 0.0}


def make_detector(name: str = DEFAULT_DETECTOR, min_radius: float = 8.0, max_radius: float = 160.0) -> CircleDetector:
    """The detector called ``name`` (one of :data:`DETECTORS`) for circle radii in [min_radius, max_radius] px.

    Raises
    ------
    ValueError
        For an unknown name.
    """
    lo, hi = int(np.floor(min_radius)), int(np.ceil(max_radius))
    if name == "hough":
        return HoughCircleDetector(HoughConfig(min_radius=lo, max_radius=hi))
    if name == "rim":
        return RimCircleDetector(RimConfig(min_radius=lo, max_radius=hi))
    if name == "symmetry":
        return SymmetryCircleDetector(SymmetryConfig(min_radius=lo, max_radius=hi))
    if name == "learned":
        from agents.perception.learned import LearnedCircleDetector, LearnedConfig

        return LearnedCircleDetector(LearnedConfig(min_radius=min_radius, max_radius=max_radius))
    raise ValueError(f"unknown detector {name!r} (expected one of {', '.join(DETECTORS)})")
