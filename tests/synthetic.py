"""Test helpers over :mod:`decentral.synthetic` (the exact log generator, re-exported here)."""

from __future__ import annotations

from decentral.observations import ObservationLog, Step
from decentral.synthetic import (  # noqa: F401  (re-exported for the tests)
    K_DEFAULT,
    R_CAM_IN_STRUT,
    camera,
    circle_motion,
    l_config,
    line_config,
    make_log,
    true_relative,
)


def without(log: ObservationLog, name: str, *, config: bool = False) -> ObservationLog:
    """The log as the others see it when ``name``'s agent sends nothing: no odometry or cameras of it, and
    no configuration unless ``config`` (the others may know it from an announcement made earlier)."""
    prefix = name + "/"
    steps = tuple(Step(t=s.t, config={a: c for a, c in s.config.items() if a != name or config},
                       odometry={a: o for a, o in s.odometry.items() if a != name},
                       detections={k: d for k, d in s.detections.items() if not k.startswith(prefix)},
                       mounts={k: m for k, m in s.mounts.items() if not k.startswith(prefix)}) for s in log.steps)
    cams = {k: c for k, c in log.cameras.items() if c.assembly != name}
    return ObservationLog(log.node_radius, log.assemblies, cams, steps)
