"""Readers for the files robots record: odometry trajectories (TUM, CSV), frame-time lists, layouts.

Every reader validates what it reads and raises :class:`InputError` naming the file and the line or
field; none returns NaN.

- TUM trajectory: lines ``t x y z qx qy qz qw`` (whitespace-separated, ``#`` comments).
- CSV trajectory: a header row naming the columns; needs ``t`` (or ``time``/``timestamp``), ``x``,
  ``y``, optionally ``z``, and the heading as ``yaw`` (or ``theta``) in radians or as a quaternion
  ``qx, qy, qz, qw``. Other columns are ignored.
- Times file: one time in seconds per line (KITTI's ``times.txt``), ``#`` comments.
- Layout file ``decentral.layout/1`` (JSON): ``{"format": "decentral.layout/1", "layouts": [{"t": 0.0,
  "nodes": {"0": [x, y, z], ...}}, ...]}``: the node layout of one assembly over time; the layout in
  force at time t is the last one whose ``t`` is at most t (the first one before that). An entry may
  also give ``"mounts": {"cam0": {"R": ..., "p": ...}}``: camera strut poses in the root frame that
  override the rig's ``strut_in_root`` while the entry is in force (a strut moved by reconfiguration).
"""

from __future__ import annotations

import csv
import os
from dataclasses import dataclass

import numpy as np

from decentral.errors import InputError
from decentral.observations import Pose
from sims.io.kinds import require_kind
from sims.io.log_json import load_json, parse_pose
from sims.io.text import read_text
from sims.io.trajectories import Trajectory
from sims.io.validate import (
    MAX_METRES,
    require_int_key,
    require_list,
    require_mapping,
    require_number,
    require_vector,
)

__all__ = ["LAYOUT_FORMAT", "Layout", "yaw_from_quaternion", "checked_trajectory", "parse_nodes",
           "read_trajectory_file",
           "read_times", "read_layout"]

LAYOUT_FORMAT = "decentral.layout/1"


def yaw_from_quaternion(qx, qy, qz, qw) -> np.ndarray:
    """Yaw [rad] (rotation about z, ZYX convention) of unit quaternions; roll and pitch are dropped."""
    qx, qy, qz, qw = (np.asarray(a, float) for a in (qx, qy, qz, qw))
    return np.arctan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))


def _finite_row(parts: list[str], n: int, where: str) -> list[float]:
    if len(parts) != n:
        raise InputError(f"expected {n} numbers, got {len(parts)}", field=where)
    try:
        values = [float(x) for x in parts]
    except ValueError:
        raise InputError("not a number", field=where) from None
    if not np.all(np.isfinite(values)):
        raise InputError("must be finite", field=where)
    return values


def checked_trajectory(t, p, yaw, source: str) -> Trajectory:
    """A :class:`Trajectory` after checking that it has samples and that its times increase."""
    t, p, yaw = np.asarray(t, float), np.asarray(p, float).reshape(-1, 3), np.asarray(yaw, float)
    if len(t) == 0:
        raise InputError("no odometry samples", source=source)
    bad = np.flatnonzero(np.diff(t) <= 0)
    if len(bad):
        raise InputError(f"sample times must increase ({t[bad[0] + 1]:g} after {t[bad[0]]:g})",
                         source=source, field=f"sample {bad[0] + 1}")
    return Trajectory(t, p, yaw)


def _read_tum(path: str | os.PathLike) -> Trajectory:
    rows = []
    for number, line in enumerate(read_text(path).splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if line:
            try:
                rows.append(_finite_row(line.replace(",", " ").split(), 8, f"line {number}"))
            except InputError as err:
                raise err.located(str(path)) from None
    arr = np.array(rows, float).reshape(-1, 8)
    return checked_trajectory(arr[:, 0], arr[:, 1:4], yaw_from_quaternion(*arr[:, 4:8].T), str(path))


_TIME_COLUMNS = ("t", "time", "timestamp")


def _read_csv(path: str | os.PathLike) -> Trajectory:
    lines = read_text(path).splitlines()
    reader = csv.reader(line for line in lines if line.strip() and not line.lstrip().startswith("#"))
    header = [h.strip().lower() for h in next(reader, [])]
    col = {name: i for i, name in enumerate(header)}
    time_col = next((c for c in _TIME_COLUMNS if c in col), None)
    yaw_col = next((c for c in ("yaw", "theta") if c in col), None)
    quat = all(c in col for c in ("qx", "qy", "qz", "qw"))
    if time_col is None or "x" not in col or "y" not in col or not (yaw_col or quat):
        raise InputError("the header must name t, x, y (z optional) and yaw/theta or qx, qy, qz, qw",
                         source=str(path), field="header")
    wanted = [time_col, "x", "y", *(["z"] if "z" in col else []), *([yaw_col] if yaw_col else ["qx", "qy", "qz", "qw"])]
    rows = []
    for number, row in enumerate(reader, 2):
        try:
            cells = [row[col[c]] if col[c] < len(row) else "" for c in wanted]
            rows.append(_finite_row(cells, len(wanted), f"row {number}"))
        except InputError as err:
            raise err.located(str(path)) from None
    arr = np.array(rows, float).reshape(-1, len(wanted))
    values = dict(zip(wanted, arr.T))
    p = np.stack([values["x"], values["y"], values.get("z", np.zeros(len(arr)))], axis=1)
    yaw = values[yaw_col] if yaw_col else yaw_from_quaternion(values["qx"], values["qy"], values["qz"], values["qw"])
    return checked_trajectory(values[time_col], p, yaw, str(path))


def read_trajectory_file(path: str | os.PathLike) -> Trajectory:
    """Read a TUM (any suffix but ``.csv``) or CSV (``.csv``) odometry trajectory."""
    return _read_csv(path) if str(path).lower().endswith(".csv") else _read_tum(path)


def read_times(path: str | os.PathLike) -> np.ndarray:
    """Read a times file: one strictly increasing time [s] per line."""
    times = []
    for number, line in enumerate(read_text(path).splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if line:
            try:
                times.append(_finite_row(line.split(), 1, f"line {number}")[0])
            except InputError as err:
                raise err.located(str(path)) from None
    times = np.array(times, float)
    if np.any(np.diff(times) <= 0):
        raise InputError("times must increase", source=str(path))
    return times


@dataclass(frozen=True)
class Layout:
    """An assembly's node layouts (and camera strut mounts) over time.

    ``nodes[i]`` (node id -> centre in the root horizontal frame) and ``mounts[i]`` (camera name ->
    strut pose in the root frame, overriding the rig's ``strut_in_root``) are in force from
    ``times[i]`` on; the first entry also before ``times[0]``.
    """

    times: np.ndarray
    nodes: tuple[dict[int, np.ndarray], ...]
    mounts: tuple[dict[str, Pose], ...] = ()
    source: str = ""  #: the layout file it was read from ("" when given inline in the rig)

    def field(self, index: int, node: int, inline: str) -> str:
        """The field path of ``node`` in entry ``index``: in the layout file, or ``inline`` + ``.ID`` in the rig."""
        return f"layouts[{index}].nodes.{node}" if self.source else f"{inline}.{node}"

    def index(self, t: float) -> int:
        """Index of the entry in force at time ``t``."""
        return max(int(np.searchsorted(self.times, t, side="right")) - 1, 0)

    def at(self, t: float) -> dict[int, np.ndarray]:
        """The node layout in force at time ``t``."""
        return self.nodes[self.index(t)]

    def mounts_at(self, t: float) -> dict[str, Pose]:
        """The strut mounts (camera name -> pose) in force at time ``t``."""
        return self.mounts[self.index(t)] if self.mounts else {}


def parse_nodes(value, field: str) -> dict[int, np.ndarray]:
    """Node id -> centre (3,) in the root horizontal frame, from a JSON/TOML mapping."""
    value = require_mapping(value, field)
    if not value:
        raise InputError("an assembly needs at least one node", field=field)
    return {require_int_key(k, f"{field}.{k}"): require_vector(c, f"{field}.{k}", 3, MAX_METRES)
            for k, c in value.items()}


def read_layout(path: str | os.PathLike) -> Layout:
    """Read and validate a ``decentral.layout/1`` file."""
    require_kind(path, LAYOUT_FORMAT)
    doc = load_json(path)
    try:
        doc = require_mapping(doc, "(top level)")
        if doc.get("format") != LAYOUT_FORMAT:
            raise InputError(f"expected {LAYOUT_FORMAT!r}, got {doc.get('format')!r}", field="format")
        entries = require_list(doc.get("layouts"), "layouts")
        if not entries:
            raise InputError("no layouts", field="layouts")
        times, nodes, mounts = [], [], []
        for i, entry in enumerate(entries):
            entry = require_mapping(entry, f"layouts[{i}]")
            times.append(require_number(entry.get("t"), f"layouts[{i}].t"))
            if i and times[-1] <= times[-2]:
                raise InputError("layout times must increase", field=f"layouts[{i}].t")
            nodes.append(parse_nodes(entry.get("nodes"), f"layouts[{i}].nodes"))
            raw = require_mapping(entry.get("mounts", {}), f"layouts[{i}].mounts")
            mounts.append({cam: parse_pose(pose, f"layouts[{i}].mounts.{cam}") for cam, pose in raw.items()})
    except InputError as err:
        raise err.located(str(path)) from None
    return Layout(np.array(times), tuple(nodes), tuple(mounts), str(path))
