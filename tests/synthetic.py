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


#: the lies a member can tell with its own data (:func:`lying`)
LIES = ("detections", "odometry", "layout", "node_ids")


def lying(log: ObservationLog, liar: str, lie: str, victim: str | None = None) -> ObservationLog:
    """``log`` with ``liar``'s own data falsified: ``detections`` every detection of its cameras shifted 40 px
    in u; ``odometry`` its motions (translation and yaw) scaled 5x; ``layout`` its configuration stretched
    1.5x about its root; ``node_ids`` its configuration also listing every node id of ``victim`` (the
    next assembly by default) at made-up centres."""
    import dataclasses

    import numpy as np

    from decentral.observations import Odometry

    names = list(log.assemblies)
    victim = victim or names[(names.index(liar) + 1) % len(names)]
    prefix = liar + "/"
    claimed = sorted({int(i) for s in log.steps for i in s.config.get(victim, {})})
    steps = []
    for s in log.steps:
        config, odometry, detections = dict(s.config), dict(s.odometry), dict(s.detections)
        if lie == "detections":
            detections = {k: tuple(dataclasses.replace(d, u=d.u + 40.0) for d in ds) if k.startswith(prefix) else ds
                          for k, ds in detections.items()}
        elif lie == "odometry" and liar in odometry:
            o = odometry[liar]
            odometry[liar] = Odometry(np.asarray(o.dp, float) * 5.0, float(o.dtheta) * 5.0)
        elif lie == "layout":
            config[liar] = {i: 1.5 * np.asarray(c, float) for i, c in config[liar].items()}
        elif lie == "node_ids":
            config[liar] = {**config[liar], **{i: np.array([0.5, 0.1 * j, 0.0]) for j, i in enumerate(claimed)}}
        elif lie not in LIES:
            raise ValueError(f"unknown lie {lie!r}")
        steps.append(dataclasses.replace(s, config=config, odometry=odometry, detections=detections))
    return dataclasses.replace(log, steps=tuple(steps))
