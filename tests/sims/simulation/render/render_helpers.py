"""Tiny worlds for rendering tests: one camera looking along +x of W at spheres placed by hand."""

import numpy as np

from sims.simulation.world.camera import CameraSpec, default_K
from sims.simulation.world.rigs import strut_camera
from sims.simulation.world.shapes import NODE_RADIUS, Shape
from sims.simulation.world.world import AssemblyTrack, World

CAM_HEIGHT = 0.3  # the observer's root stands on a 0.24 m block: camera centre at z = 0.34


def tiny_world(targets, *, yaw=0.0, struts=False):
    """A world whose camera (A0/cam0) sits at (0.15, 0, 0.34) in W looking along +x.

    ``targets`` is a list of (node id, (x, y, z) centre in W); each becomes a one-node assembly
    (or, with ``struts``, all of them form one assembly rooted at the first, joined in a chain).
    """
    steps = 2
    observer = Shape((900,), np.zeros((1, 3)))
    tracks = [AssemblyTrack("A0", CAM_HEIGHT - NODE_RADIUS, np.zeros((steps, 2)), np.zeros(steps), (observer,) * steps)]
    if struts:
        ids = tuple(i for i, _ in targets)
        base = np.asarray(targets[0][1], float)
        rel = np.array([np.asarray(c, float) - base for _, c in targets])
        shape = Shape(ids, rel, tuple(zip(ids[:-1], ids[1:])))
        tracks.append(AssemblyTrack("A1", base[2] - NODE_RADIUS, np.tile(base[:2], (steps, 1)),
                                    np.full(steps, yaw), (shape,) * steps))
    else:
        for n, (node, c) in enumerate(targets):
            shape = Shape((node,), np.zeros((1, 3)))
            tracks.append(AssemblyTrack(f"A{n + 1}", c[2] - NODE_RADIUS, np.tile(np.asarray(c[:2], float), (steps, 1)),
                                        np.full(steps, yaw), (shape,) * steps))
    rig = strut_camera("A0", "cam0", at=(0.1, 0.0, 0.0), look_yaw=0.0, spec=CameraSpec(default_K()))
    return World(NODE_RADIUS, np.arange(steps) * 0.2, tuple(tracks), (rig,))
