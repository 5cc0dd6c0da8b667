"""One assembly's part of an observation log: what ``decentral agent`` reads.

A *part* is itself a valid ``decentral.log/1`` (so every reader and validator applies), restricted to
what one assembly's own sensors give:

- ``assemblies`` lists **every** assembly of the log, in the log's order (agents index the others
  by it, so every part of one run must list the same names in the same order), but only the owner's
  entry has ``cameras``;
- each step keeps its ``t``, and only the owner's ``config`` entry, ``odometry`` entry, camera
  ``detections`` and ``mounts``;
- the top-level field ``"part"`` names the owner (readers of ``decentral.log/1`` ignore it).

:func:`split_log` makes the parts of a log; :func:`part_owner` checks that a part is the named agent's.
"""

from __future__ import annotations

import os

from decentral.errors import InputError
from decentral.observations import ObservationLog, Step
from sims.io.atomic import write_json_atomic
from sims.io.kinds import require_kind
from sims.io.log_json import LOG_FORMAT, load_json, log_to_dict, parse_log

__all__ = ["split_log", "part_of", "write_part", "read_part"]


def part_of(log: ObservationLog, name: str) -> ObservationLog:
    """The part of ``log`` that assembly ``name`` observes itself (see the module docstring)."""
    if name not in log.assemblies:
        raise InputError(f"no assembly {name!r} in the log", field="assemblies")
    prefix = name + "/"
    cameras = {key: cam for key, cam in log.cameras.items() if cam.assembly == name}
    steps = tuple(
        Step(
            t=step.t,
            config={name: step.config[name]} if name in step.config else {},
            odometry={name: step.odometry[name]} if name in step.odometry else {},
            detections={key: d for key, d in step.detections.items() if key.startswith(prefix)},
            mounts={key: m for key, m in step.mounts.items() if key.startswith(prefix)},
        )
        for step in log.steps
    )
    return ObservationLog(node_radius=log.node_radius, assemblies=log.assemblies, cameras=cameras, steps=steps)


def split_log(log: ObservationLog) -> dict[str, ObservationLog]:
    """Every assembly's part of ``log``: name -> part."""
    return {name: part_of(log, name) for name in log.assemblies}


def write_part(path: str | os.PathLike, part: ObservationLog, name: str) -> None:
    """Write ``name``'s part atomically as ``decentral.log/1`` with ``"part": name``."""
    doc = log_to_dict(part)
    doc["part"] = name
    write_json_atomic(path, doc)


_MAKE = "`decentral parts LOG.json -o DIR` makes each assembly's part of a log"


def read_part(path: str | os.PathLike, name: str) -> ObservationLog:
    """Read a part and check it is ``name``'s: its ``part`` field (if any) names it and it holds no other
    assembly's cameras, configuration, odometry or detections."""
    require_kind(path, LOG_FORMAT)
    doc = load_json(path)
    try:
        log = parse_log(doc)
    except InputError as err:
        raise err.located(str(path)) from None
    owner = doc.get("part", name)
    if owner != name:
        raise InputError(f"this is {owner!r}'s part, not {name!r}'s", source=str(path), field="part")
    if name not in log.assemblies:
        raise InputError(f"{name!r} is not listed", source=str(path), field="assemblies")
    foreign = [key for key, cam in log.cameras.items() if cam.assembly != name]
    for k, step in enumerate(log.steps):
        others = [a for a in (*step.config, *step.odometry) if a != name]
        if others:
            raise InputError(f"holds data of {others[0]!r}: a part has its owner's only ({_MAKE})", source=str(path),
                             field=f"steps[{k}]")
    if foreign:
        raise InputError(f"holds another assembly's camera {foreign[0]!r} ({_MAKE})", source=str(path),
                         field="assemblies")
    return log
