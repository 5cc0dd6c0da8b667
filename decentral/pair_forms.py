"""One observer's own factors: its detections in its root frame, and the quadratic forms of its pairs.

What an assembly agent computes from its own sensors alone (:mod:`agents.assembly`): the
back-projected centres of the nodes its cameras see (Liu et al. 2024 eq. (1), (4)) with their weights, and,
once it knows which assembly owns each node, the cost form of every directed pair ``observer ->
target`` over the window (for its ADMM subproblem) and the same factors step by step (the forms it
shares: a step's form is built from that step's detections alone, so it is bit-identical from window
to window).
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from decentral.admm import LocalProblem, quadratic_form
from decentral.factors import NoiseModel, detection_weights
from decentral.geometry import backproject
from decentral.observations import Camera, Detection, Pose

__all__ = ["own_detections", "pair_forms"]


def own_detections(cameras: Sequence[Camera], detections: Mapping[str, Sequence[Detection]],
                   mounts: Mapping[str, Pose], own_nodes, node_radius: float,
                   noise: NoiseModel) -> list[tuple[int, np.ndarray, float]]:
    """An assembly's detections of other assemblies' nodes as ``(node, centre (3,), weight)``.

    Parameters
    ----------
    cameras : sequence of Camera
        The assembly's own cameras.
    detections : Mapping[str, sequence of Detection]
        Camera key -> identified detections of the step.
    mounts : Mapping[str, Pose]
        Camera key -> strut pose overriding the default at this step.
    own_nodes : container of int
        The assembly's own node ids (their detections carry no relative information: skipped).
    node_radius : float
        Node radius r_0 (m).
    noise : NoiseModel
        Factor weights.

    Returns
    -------
    list of (int, ndarray, float)
        Node id, its centre in the observer's root frame (3,) (Liu et al. 2024 eq. (1), (4)), isotropic weight.
    """
    out = []
    for cam in cameras:
        dets = [d for d in detections.get(cam.key, ()) if d.node not in own_nodes]
        if not dets:
            continue
        u, v, r = (np.array([getattr(d, a) for d in dets]) for a in ("u", "v", "r"))
        p_cam = backproject(cam.K, u, v, r, node_radius)  # Liu et al. 2024 eq. (1)
        pose = cam.in_root(mounts.get(cam.key))
        t = pose.apply(p_cam)  # eq. (4): t_i in the own root frame
        f = 0.5 * (cam.K[0, 0] + cam.K[1, 1])
        w = detection_weights(p_cam[:, 2], r, f, noise)
        out += [(d.node, t[i], float(w[i])) for i, d in enumerate(dets)]
    return out


def pair_forms(observer: str, target: str, facts) -> tuple[LocalProblem, list[LocalProblem]]:
    """The cost forms of the directed pair ``observer -> target`` (Liu et al. 2024 eq. (4), (5)).

    Parameters
    ----------
    observer, target : str
        The assemblies.
    facts : sequence of (int, ndarray, ndarray, float)
        ``(step, q, t, w)``: a node's centre ``q`` (3,) in the target's root frame, its measured centre
        ``t`` (3,) in the observer's root frame, and its weight.

    Returns
    -------
    window : LocalProblem
        One form over the poses ``(observer, k), (target, k)`` of every step ``k`` with facts.
    steps : list of LocalProblem
        The same factors as one form per step (sorted by step), each over that step's two poses.
    """
    keys, io, ia, q, t, w = [], [], [], [], [], []
    slot = {}
    for k, qk, tk, wk in facts:
        if k not in slot:
            slot[k] = len(keys)
            keys += [(observer, k), (target, k)]
        io.append(slot[k])
        ia.append(slot[k] + 1)
        q.append(qk), t.append(tk), w.append(wk)
    window = quadratic_form(keys, visual=(np.array(io), np.array(ia), np.array(q), np.array(t), np.array(w)))
    per_step = {}
    for k, qk, tk, wk in facts:
        per_step.setdefault(k, []).append((qk, tk, wk))
    steps = [quadratic_form([(observer, k), (target, k)], visual=(
        np.zeros(len(f), int), np.ones(len(f), int), np.array([x[0] for x in f]),
        np.array([x[1] for x in f]), np.array([x[2] for x in f])))
        for k, f in sorted(per_step.items())]
    return window, steps
