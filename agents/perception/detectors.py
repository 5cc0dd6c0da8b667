"""The circle detectors by name: ``"hough"`` (the default), ``"rim"`` and ``"symmetry"`` (opt-in).

``"hough"`` is :class:`~agents.perception.hough.HoughCircleDetector`: fast (about 15-30 ms of CPU
per 1024 x 768 frame) and the best on the rendered frames. ``"rim"`` is
:class:`~agents.perception.rim.RimCircleDetector`: it reports the sphere's outline where the default
fits the tag (large spheres coloured like the floor, a tag near the limb, partly hidden spheres), at
about five times the cost. ``"symmetry"`` is :class:`~agents.perception.symmetry_detector.SymmetryCircleDetector`:
colour-edge radial-symmetry candidates verified on the rim; the best recall on the varied frames at
about three times the default's cost, but worse than the default on the rendered ``table1`` frames.
``"learned"`` is :class:`~agents.perception.learned.LearnedCircleDetector`: two small networks
shipped with the package (proposals, then a second stage per circle), run by OpenCV's ``dnn``.
docs/perception.md gives the measured figures.
"""

from __future__ import annotations

import numpy as np

from agents.perception.hough import HoughCircleDetector, HoughConfig
from agents.perception.rim import RimCircleDetector, RimConfig
from agents.perception.symmetry_detector import SymmetryCircleDetector, SymmetryConfig
from agents.perception.types import CircleDetector

__all__ = ["DETECTORS", "make_detector"]

DETECTORS = ("hough", "rim", "symmetry", "learned")


def make_detector(name: str = "hough", min_radius: float = 8.0, max_radius: float = 160.0) -> CircleDetector:
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
