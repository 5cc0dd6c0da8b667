"""Per-assembly trajectories relative to a reference, from an estimate or a ground truth, and their
files in the formats trajectory-evaluation tools read (TUM, KITTI, CSV).

A trajectory here is what ``decentral.estimate/1`` holds for one assembly: at each time it is
placed, the pose of its root horizontal frame in the reference's root horizontal frame at the same
time, ``p`` (3,) and yaw ``theta`` (Liu et al. 2024 eq. (19)). Its 3D form is the rotation about z by
``theta``, i.e. the unit quaternion ``(qx, qy, qz, qw) = (0, 0, sin(theta/2), cos(theta/2))``.

File formats written by :func:`write_trajectories` (one file per assembly, named after it):

- ``tum``: ``DIR/<NAME>.tum``, one line per pose ``t x y z qx qy qz qw`` (the TUM RGB-D format,
  read by ``evo_ape tum`` / ``evo_traj tum``).
- ``kitti``: ``DIR/<NAME>.txt``, one line per pose with the 12 entries of the 3x4 matrix ``[R | p]``
  row by row (the KITTI odometry format, read by ``evo_* kitti``), and, since KITTI poses carry no
  time, ``DIR/<NAME>.times.txt`` with one time in seconds per line (as KITTI's ``times.txt``).
- ``csv``: ``DIR/<NAME>.csv`` with the header ``t,x,y,z,theta,qx,qy,qz,qw``.

``<NAME>`` is the assembly name percent-encoded as ``decentral keys`` names its files
(:func:`sims.io.paths.name_stem`: ``r/1`` -> ``r%2F1``), so every name gives one file in ``DIR``.

Numbers are written with Python's shortest round-trip representation, so nothing is lost.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from decentral.errors import InputError
from decentral.geometry import wrap_angle
from decentral.metrics import GroundTruth, relative_truth
from decentral.observations import Estimate, require_estimate
from sims.io.atomic import write_atomic
from sims.io.paths import name_stem

__all__ = [
    "FORMATS",
    "Trajectory",
    "estimate_trajectories",
    "truth_trajectories",
    "trajectory_lines",
    "write_trajectories",
]

#: format name -> what it writes (for ``--help`` and the README)
FORMATS: dict[str, str] = {
    "tum": "DIR/<NAME>.tum: lines 't x y z qx qy qz qw' (TUM RGB-D; evo_ape tum)",
    "kitti": "DIR/<NAME>.txt: 3x4 [R|p] row by row per line, and DIR/<NAME>.times.txt (KITTI odometry; evo_ape kitti)",
    "csv": "DIR/<NAME>.csv: header t,x,y,z,theta,qx,qy,qz,qw",
}


@dataclass(frozen=True)
class Trajectory:
    """A planar trajectory: an assembly's poses relative to the reference at the times it is placed
    (what the exporters write), or a robot's odometry poses in its odometry frame (what build-log reads).

    Attributes
    ----------
    t : ndarray, shape (T,)
        Times [s], increasing.
    p : ndarray, shape (T, 3)
        Positions of the assembly's root in the reference's root horizontal frame (or the odometry frame) [m].
    yaw : ndarray, shape (T,)
        Yaw ``theta`` of the assembly's root relative to the reference's [rad].
    """

    t: np.ndarray
    p: np.ndarray
    yaw: np.ndarray

    def quaternions(self) -> np.ndarray:
        """Unit quaternions ``(qx, qy, qz, qw)`` (T, 4) of the rotations about z by ``yaw``."""
        half = 0.5 * self.yaw
        zeros = np.zeros_like(half)
        return np.stack([zeros, zeros, np.sin(half), np.cos(half)], axis=1)

    def matrices(self) -> np.ndarray:
        """Poses as 3x4 matrices ``[R | p]`` (T, 3, 4), R the rotation about z by ``yaw``."""
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        out = np.zeros((len(self.t), 3, 4))
        out[:, 0, 0], out[:, 0, 1], out[:, 1, 0], out[:, 1, 1] = c, -s, s, c
        out[:, 2, 2] = 1.0
        out[:, :, 3] = self.p
        return out


def _relative_to(traj: dict[str, Trajectory], old: str, new: str) -> dict[str, Trajectory]:
    """Re-express trajectories written in ``old``'s frame in ``new``'s (``new`` must be placed).

    At each time both are placed, the pose of B in ``new`` is ``(new in old)^-1 (B in old)``
    (planar composition); ``old`` itself becomes ``(new in old)^-1``.
    """
    base = traj[new]
    where = {float(t): i for i, t in enumerate(base.t)}
    others = {name: tr for name, tr in traj.items() if name != new}
    others[old] = Trajectory(base.t, np.zeros_like(base.p), np.zeros_like(base.yaw))
    out = {}
    for name, tr in others.items():
        rows = [(i, where[float(t)]) for i, t in enumerate(tr.t) if float(t) in where]
        if not rows:
            continue
        i, j = (np.array(x) for x in zip(*rows))
        th0 = base.yaw[j]
        d = tr.p[i] - base.p[j]
        c, s = np.cos(th0), np.sin(th0)
        p = np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], d[:, 2]], axis=1)
        out[name] = Trajectory(tr.t[i], p, np.asarray(wrap_angle(tr.yaw[i] - th0)))
    return out


def estimate_trajectories(estimate: Estimate, reference: str | None = None) -> dict[str, Trajectory]:
    """Per placed assembly, its trajectory in the estimate (assemblies never placed are absent).

    Parameters
    ----------
    estimate : Estimate
        A ``decentral.estimate/1`` in memory.
    reference : str, optional
        Write the poses relative to this assembly instead of ``estimate.reference``; only the times
        at which it is placed remain, and the estimate's reference becomes one of the trajectories.
    """
    estimate = require_estimate(estimate)
    rows: dict[str, list] = {}
    for step in estimate.steps:
        for name, pose in step.poses.items():
            rows.setdefault(name, []).append((step.t, *np.asarray(pose.p, dtype=float), float(pose.theta)))
    traj = {}
    for name, values in rows.items():
        arr = np.array(values, dtype=float)
        traj[name] = Trajectory(arr[:, 0], arr[:, 1:4], np.asarray(wrap_angle(arr[:, 4])))
    if reference is None or reference == estimate.reference:
        return traj
    if reference not in traj:
        raise InputError(f"{reference!r} is never placed in the estimate", field="reference")
    return _relative_to(traj, estimate.reference, reference)


def truth_trajectories(truth: GroundTruth, reference: str) -> dict[str, Trajectory]:
    """Every assembly's true trajectory relative to ``reference`` (Liu et al. 2024 eq. (19) on true poses).

    The same relation :func:`decentral.metrics.score_estimate` scores against, at every truth step.
    """
    if not isinstance(truth, GroundTruth):
        raise InputError(f"expected a GroundTruth, got {type(truth).__name__}", field="truth")
    if reference not in truth.R:
        raise InputError(f"no assembly {reference!r} in the truth", field="reference")
    out = {}
    for name in truth.R:
        if name != reference:
            p, theta = relative_truth(truth, reference, name)
            out[name] = Trajectory(np.asarray(truth.times, dtype=float), p, theta)
    return out


def _num(x: float) -> str:
    return repr(float(x))


def trajectory_lines(traj: Trajectory, fmt: str) -> dict[str, list[str]]:
    """The text lines of ``traj`` in format ``fmt``, per file suffix (``".tum"``, ``".txt"``, ...)."""
    if fmt == "tum":
        q = traj.quaternions()
        return {".tum": [" ".join(map(_num, (t, *p, *qq))) for t, p, qq in zip(traj.t, traj.p, q)]}
    if fmt == "kitti":
        return {".txt": [" ".join(map(_num, m.ravel())) for m in traj.matrices()],
                ".times.txt": [_num(t) for t in traj.t]}
    if fmt == "csv":
        q = traj.quaternions()
        rows = [",".join(map(_num, (t, *p, th, *qq))) for t, p, th, qq in zip(traj.t, traj.p, traj.yaw, q)]
        return {".csv": ["t,x,y,z,theta,qx,qy,qz,qw", *rows]}
    raise InputError(f"unknown format {fmt!r}; known: {', '.join(FORMATS)}", field="format")


def _trajectory_files(trajectories: dict[str, Trajectory], outdir: str | os.PathLike, fmt: str) -> list[tuple[Path, str]]:
    """The files :func:`write_trajectories` writes, as ``(path, text)`` pairs, without touching the disk.

    Raises :class:`InputError` (a name that gives no file name, an unknown format) before anything is written.
    """
    files: list[tuple[Path, str]] = []
    for name, traj in trajectories.items():
        stem = name_stem(name, field=f"assembly {name[:40]!r}")
        for suffix, lines in trajectory_lines(traj, fmt).items():
            files.append((Path(outdir) / f"{stem}{suffix}", "\n".join(lines) + "\n"))
    return files


def write_trajectories(trajectories: dict[str, Trajectory], outdir: str | os.PathLike, fmt: str) -> list[Path]:
    """Write one file (KITTI: two) per trajectory into ``outdir``, each atomically.

    Every name and line is checked before ``outdir`` (and its parents) is created and the first file
    written, so bad input writes nothing. Returns the paths written, in the order of ``trajectories``.
    """
    files = _trajectory_files(trajectories, outdir, fmt)
    try:
        Path(outdir).mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise InputError(f"cannot create output folder ({err.strerror})", source=str(outdir)) from None
    for path, text in files:
        write_atomic(path, lambda fh, text=text: fh.write(text))
    return [path for path, _ in files]
