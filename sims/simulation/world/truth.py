"""Ground truth of a simulated run and its JSON form ``decentral.truth/1``.

.. code-block:: json

    {"format": "decentral.truth/1", "node_radius": 0.06, "reference": "A0",
     "meta": {"scenario": "table1", "seed": 0},
     "steps": [{"t": 0.0,
                "poses": {"A0": {"R": [[1,0,0],[0,1,0],[0,0,1]], "p": [0, 0, 0.81]}, ...},
                "visible": {"A0/cam0": [{"id": 5, "u": 611.2, "v": 402.9, "r": 23.1, "covered": 0.0}]}}]}

``poses`` holds every assembly root's pose (R_{H_r}^W, p_{H_r}^W) in one world frame W (z up, floor
at ``z = 0``). ``visible`` lists, per camera, the nodes the geometric model finds in view at that step
with their noiseless circle (Liu et al. 2024 eq. (1) inverted) and the fraction of the circle hidden by
nearer nodes, before drop-outs and noise. Runs rendered with frames add, per step and camera,
``"frames": {"A0/cam0": {"file": "frames/A0/cam0/00000.png", "nodes": [{"id", "u", "v", "r", "su",
"sv", "sr", "visible"}]}}``: every node with a visible pixel, its eq. (1) circle, its exact
silhouette circle (``su``, ``sv``, ``sr``) and the visible fraction of its silhouette.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from decentral.errors import InputError
from decentral.metrics import GroundTruth
from sims.io.kinds import require_kind
from sims.io.validate import (
    MAX_METRES,
    MAX_SECONDS,
    MIN_METRES,
    require_number,
    require_positive,
    require_rotation,
    require_vector,
)

__all__ = ["TRUTH_FORMAT", "Truth", "truth_to_dict", "parse_truth", "read_truth", "write_truth"]

TRUTH_FORMAT = "decentral.truth/1"


@dataclass(frozen=True)
class Truth:
    """Ground truth of a run: world poses, visibility, and a free-form description.

    Attributes
    ----------
    poses : GroundTruth
        Root poses of every assembly in W at every step.
    node_radius : float
    reference : str
        The assembly an estimate of this run is relative to by default.
    visible : tuple[dict, ...]
        Per step, camera key -> list of ``{"id", "u", "v", "r", "covered"}`` dicts.
    meta : dict
    frames : tuple[dict, ...]
        Per step, camera key -> ``{"file", "nodes"}`` for rendered frames (empty without frames).
    """

    poses: GroundTruth
    node_radius: float
    reference: str
    visible: tuple = ()
    meta: dict = field(default_factory=dict)
    frames: tuple = ()


def truth_to_dict(truth: Truth) -> dict:
    """The ``decentral.truth/1`` document of ``truth``."""
    names = list(truth.poses.R)
    steps = []
    for k, t in enumerate(truth.poses.times):
        raw: dict[str, Any] = {
            "t": float(t),
            "poses": {n: {"R": truth.poses.R[n][k].tolist(), "p": truth.poses.p[n][k].tolist()} for n in names},
        }
        if truth.visible:
            raw["visible"] = truth.visible[k]
        if truth.frames:
            raw["frames"] = truth.frames[k]
        steps.append(raw)
    return {
        "format": TRUTH_FORMAT,
        "node_radius": truth.node_radius,
        "reference": truth.reference,
        "meta": truth.meta,
        "steps": steps,
    }


def parse_truth(doc: Any) -> Truth:
    """Validate a decoded ``decentral.truth/1`` document."""
    if not isinstance(doc, dict) or doc.get("format") != TRUTH_FORMAT:
        got = doc.get("format") if isinstance(doc, dict) else None
        raise InputError(f"expected {TRUTH_FORMAT!r}, got {got!r}", field="format")
    steps = doc.get("steps")
    if not isinstance(steps, list) or not steps:
        raise InputError("missing or empty", field="steps")
    times, R, p, visible, frames = [], {}, {}, [], []
    names = None
    for k, raw in enumerate(steps):
        if not isinstance(raw, dict) or not isinstance(raw.get("poses"), dict):
            raise InputError("missing poses", field=f"steps[{k}].poses")
        times.append(require_number(raw.get("t"), f"steps[{k}].t", MAX_SECONDS))
        if names is None:
            names = list(raw["poses"])
            R = {n: [] for n in names}
            p = {n: [] for n in names}
        if set(raw["poses"]) != set(names):
            raise InputError("every step must give the pose of every assembly", field=f"steps[{k}].poses")
        for n in names:
            pose = raw["poses"][n]
            if not isinstance(pose, dict):
                raise InputError("not a pose", field=f"steps[{k}].poses.{n}")
            R[n].append(require_rotation(pose.get("R"), f"steps[{k}].poses.{n}.R"))
            p[n].append(require_vector(pose.get("p"), f"steps[{k}].poses.{n}.p", 3, MAX_METRES))
        visible.append(raw.get("visible", {}))
        frames.append(raw.get("frames", {}))
    try:
        gt = GroundTruth(np.asarray(times), {n: np.stack(R[n]) for n in names}, {n: np.stack(p[n]) for n in names})
    except InputError as err:
        raise InputError(err.message, field=f"steps.{err.field}") from None
    radius = require_positive(doc.get("node_radius", 0.06), "node_radius", MIN_METRES, MAX_METRES)
    reference = doc.get("reference", names[0])
    if not isinstance(reference, str) or reference not in names:
        raise InputError(f"reference {reference!r} has no poses", field="reference")
    has_frames = any(frames)
    meta = doc.get("meta", {})
    if not isinstance(meta, dict):
        raise InputError("must be an object", field="meta")
    return Truth(gt, radius, reference, tuple(visible), meta,
                 tuple(frames) if has_frames else ())


def read_truth(path: str | os.PathLike) -> Truth:
    """Read and validate a ``decentral.truth/1`` file."""
    from sims.io.log_json import load_json

    require_kind(path, TRUTH_FORMAT)
    doc = load_json(path)
    try:
        return parse_truth(doc)
    except InputError as err:
        raise err.located(str(path)) from None


def write_truth(path: str | os.PathLike, truth: Truth) -> None:
    """Write ``truth`` as ``decentral.truth/1`` atomically."""
    from sims.io.atomic import write_json_atomic

    write_json_atomic(path, truth_to_dict(truth))
