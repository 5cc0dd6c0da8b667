"""Perception output ``decentral.detections/1`` (JSON): writer, validated reader, and log assembly.

.. code-block:: json

    {"format": "decentral.detections/1",
     "frames": [{"source": "f0001.png",
                 "detections": [{"u": 611.2, "v": 402.9, "r": 23.1, "score": 0.97, "id": 5, "track": 3,
                                 "tag": {"id": 5, "hamming": 0, "margin": 61.0,
                                         "corners": [[600.1, 395.0], [620.3, 395.4], [620.0, 410.8], [600.4, 410.2]]}}]}]}

A frame may carry its capture time ``"t"`` in seconds (optional; ``decentral build-log`` uses it to
place the frame in time); the times given must increase from frame to frame. ``id`` is the node id (null where neither the tag nor the track names the node), ``track`` the track
number (null when untracked). ``tag`` (optional, beyond the format's required fields) is the accepted tag read inside
the circle: its tag id, hamming distance, decision margin and image corners (canonical order).

:func:`assemble_log` fills the detections of an observation log (``decentral.log/1``) from per-frame
detections: frame k of a camera becomes that camera's detections at step k; only identified
detections (``id`` not null) enter the log.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, replace
from typing import Any, Sequence

import numpy as np

from decentral.errors import InputError
from decentral.observations import Detection, ObservationLog, require_log
from sims.io.atomic import write_json_atomic
from sims.io.kinds import require_kind
from sims.io.log_json import load_json
from sims.io.validate import (
    MAX_PIXELS,
    MIN_PIXELS,
    require_int,
    require_list,
    require_mapping,
    require_matrix,
    require_number,
    require_positive,
)

__all__ = [
    "DETECTIONS_FORMAT",
    "TagRecord",
    "DetectionRecord",
    "DetectionFrame",
    "detections_to_dict",
    "write_detections",
    "parse_detections",
    "read_detections",
    "assemble_log",
]

DETECTIONS_FORMAT = "decentral.detections/1"


@dataclass(frozen=True)
class TagRecord:
    """An accepted tag read: tag id, hamming distance, decision margin, corners (4, 2) pixels."""

    tag: int
    hamming: int
    margin: float
    corners: np.ndarray


@dataclass(frozen=True)
class DetectionRecord:
    """One detection of a frame: circle (u, v, r) px, score, node id, track number, tag read."""

    u: float
    v: float
    r: float
    score: float
    node: int | None
    track: int | None
    tag: TagRecord | None = None


@dataclass(frozen=True)
class DetectionFrame:
    """The detections of one frame, the file (or ``video#index``) it came from, and its time [s] if known."""

    source: str
    detections: tuple[DetectionRecord, ...]
    t: float | None = None


def _finite(x: float) -> float:
    return float(np.round(float(x), 4))


def detections_to_dict(frames: Sequence[DetectionFrame]) -> dict:
    """The JSON document of ``frames``."""
    out = []
    for fr in frames:
        dets = []
        for d in fr.detections:
            rec: dict[str, Any] = {
                "u": _finite(d.u), "v": _finite(d.v), "r": _finite(d.r), "score": _finite(d.score),
                "id": None if d.node is None else int(d.node),
                "track": None if d.track is None else int(d.track),
            }
            if d.tag is not None:
                rec["tag"] = {
                    "id": int(d.tag.tag), "hamming": int(d.tag.hamming), "margin": _finite(d.tag.margin),
                    "corners": [[_finite(x), _finite(y)] for x, y in np.asarray(d.tag.corners).reshape(4, 2)],
                }
            dets.append(rec)
        out.append({"source": fr.source, **({} if fr.t is None else {"t": float(fr.t)}), "detections": dets})
    return {"format": DETECTIONS_FORMAT, "frames": out}


def write_detections(path: str | os.PathLike, frames: Sequence[DetectionFrame]) -> None:
    """Write ``frames`` as ``decentral.detections/1`` to ``path``, atomically."""
    write_json_atomic(path, detections_to_dict(frames))


def _optional_int(value: Any, field: str) -> int | None:
    """``None`` for JSON null, else a JSON integer (``5``, never ``5.0`` or ``"5"``)."""
    return None if value is None else require_int(value, field)


def parse_detections(doc: Any) -> list[DetectionFrame]:
    """Validate a parsed ``decentral.detections/1`` document; raise :class:`InputError` naming the field."""
    doc = require_mapping(doc, "(document)")
    if doc.get("format") != DETECTIONS_FORMAT:
        raise InputError(f"expected format {DETECTIONS_FORMAT!r}, got {doc.get('format')!r}", field="format")
    frames, previous_t = [], -float("inf")
    for k, fr in enumerate(require_list(doc.get("frames"), "frames")):
        where = f"frames[{k}]"
        fr = require_mapping(fr, where)
        source = fr.get("source", "")
        if not isinstance(source, str):
            raise InputError("must be a string", field=f"{where}.source")
        dets = []
        for j, d in enumerate(require_list(fr.get("detections"), f"{where}.detections")):
            f = f"{where}.detections[{j}]"
            d = require_mapping(d, f)
            tag = None
            if d.get("tag") is not None:
                t = require_mapping(d["tag"], f"{f}.tag")
                corners = require_matrix(t.get("corners"), f"{f}.tag.corners", 4, 2, MAX_PIXELS)
                tag = TagRecord(
                    _optional_int(t.get("id"), f"{f}.tag.id") or 0,
                    _optional_int(t.get("hamming"), f"{f}.tag.hamming") or 0,
                    require_number(t.get("margin"), f"{f}.tag.margin"),
                    corners,
                )
            dets.append(DetectionRecord(
                require_number(d.get("u"), f"{f}.u", MAX_PIXELS),
                require_number(d.get("v"), f"{f}.v", MAX_PIXELS),
                require_positive(d.get("r"), f"{f}.r", MIN_PIXELS, MAX_PIXELS),
                require_number(d.get("score", 1.0), f"{f}.score", MAX_PIXELS),
                _optional_int(d.get("id"), f"{f}.id"),
                _optional_int(d.get("track"), f"{f}.track"),
                tag,
            ))
        t = None if fr.get("t") is None else require_number(fr["t"], f"{where}.t")
        if t is not None and not t > previous_t:  # frames are in time order
            raise InputError(f"frame times must increase ({t:g} after {previous_t:g})", field=f"{where}.t")
        previous_t = previous_t if t is None else t
        frames.append(DetectionFrame(source, tuple(dets), t))
    return frames


def read_detections(path: str | os.PathLike) -> list[DetectionFrame]:
    """Read and validate a ``decentral.detections/1`` file; errors name the file and the field."""
    require_kind(path, DETECTIONS_FORMAT)
    try:
        return parse_detections(load_json(path))
    except InputError as err:
        raise err.located(str(path)) from None


def assemble_log(
    template: ObservationLog,
    detections: dict[str, Sequence[DetectionFrame]],
    *,
    min_score: float = 0.0,
    image_sizes: dict[str, tuple[int, int]] | None = None,
) -> ObservationLog:
    """Return ``template`` with each listed camera's detections replaced by the perceived ones.

    Parameters
    ----------
    template : ObservationLog
        A complete log (assemblies, cameras, configurations, odometry); its detections for the
        cameras in ``detections`` are discarded, other cameras' are kept.
    detections : dict
        Camera key ``"assembly/camera"`` -> one :class:`DetectionFrame` per step, in step order.
    min_score : float
        Detections scoring below this stay out of the log (partly hidden rims fit worse).
    image_sizes : dict, optional
        Camera key -> (width, height): circles not wholly inside the image stay out of the log (a
        rim cut by the image border fits badly).

    Raises
    ------
    InputError
        If a camera is not declared in the template or the frame count differs from the step count.
    """
    template = require_log(template)
    for key, frames in detections.items():
        if key not in template.cameras:
            raise InputError(f"camera {key!r} is not declared in the log template", field="--camera")
        if len(frames) != len(template.steps):
            raise InputError(
                f"{len(frames)} frames for camera {key!r} but the log template has {len(template.steps)} steps",
                field="--camera",
            )
    def inside(key: str, d: DetectionRecord) -> bool:
        if not image_sizes or key not in image_sizes:
            return True
        w, h = image_sizes[key]
        return d.u - d.r >= 0 and d.v - d.r >= 0 and d.u + d.r <= w - 1 and d.v + d.r <= h - 1

    steps = []
    for k, step in enumerate(template.steps):
        dets = dict(step.detections)
        for key, frames in detections.items():
            dets[key] = tuple(
                Detection(int(d.node), float(d.u), float(d.v), float(d.r))
                for d in frames[k].detections
                if d.node is not None and d.score >= min_score and inside(key, d)
            )
        steps.append(replace(step, detections=dets))
    return replace(template, steps=tuple(steps))
