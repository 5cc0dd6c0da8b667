"""Following agents' ``--stream`` files (JSON lines) while they are written, read defensively.

``decentral agent --stream FILE`` appends one JSON object per finished step; ``decentral launch
--workdir DIR`` leaves one such file per agent process, ``DIR/<NAME>.<INCARNATION>.jsonl``.
:class:`StreamFollower` reads what was appended since the last :meth:`~StreamFollower.poll` (only whole
lines: a line still being written waits for its newline), and keeps per agent the records of its
newest incarnation merged over older ones by step. Fields are read with defaults: a record without
``poses`` places nobody, unknown fields are kept, a line that is not a JSON object is counted in
``bad_lines`` and skipped, never fatal -- the stream format may grow (a step's ``provisional`` flag,
for one) without breaking the view.
"""

from __future__ import annotations

import json
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["AgentView", "StreamFollower", "record_pose"]

_NAME = re.compile(r"^(?P<name>.+?)(?:\.(?P<inc>[0-9]+))?\.jsonl$")
#: longest line read (a corrupt file must not fill the memory)
MAX_LINE = 4 << 20


def record_pose(record: dict, assembly: str) -> tuple[float, float, float] | None:
    """``(x, y, theta)`` of ``assembly`` in a stream record, or ``None`` when it is not placed or malformed."""
    poses = record.get("poses")
    if not isinstance(poses, dict):
        return None
    pose = poses.get(assembly)
    if not isinstance(pose, dict):
        return None
    p, th = pose.get("p"), pose.get("theta")
    try:
        x, y, theta = float(p[0]), float(p[1]), float(th)
    except (TypeError, ValueError, IndexError, KeyError):
        return None
    return (x, y, theta) if all(math.isfinite(v) for v in (x, y, theta)) else None


@dataclass
class AgentView:
    """What one agent's stream says so far.

    Attributes
    ----------
    name : str
    steps : dict[int, dict]
        Step -> the newest record of it (a restarted process's record replaces the old one).
    incarnations : int
        Process incarnations seen (1 + restarts).
    last_seen : float
        Wall time (``time.time()``) when a record of this agent was last read.
    """

    name: str
    steps: dict = field(default_factory=dict)
    incarnations: int = 0
    last_seen: float = 0.0

    def latest(self) -> dict | None:
        """The record of the highest step so far."""
        return self.steps[max(self.steps)] if self.steps else None

    def counts(self) -> dict:
        """Messages, bytes and rejections (by reason) of the newest record (``{}``-safe)."""
        rec = self.latest() or {}
        counts = rec.get("counts") if isinstance(rec.get("counts"), dict) else {}
        rejected = counts.get("rejected") if isinstance(counts.get("rejected"), dict) else {}
        return {"messages": _int(counts.get("messages")), "bytes": _int(counts.get("bytes")),
                "rejected": {str(k): _int(v) for k, v in rejected.items()}}

    def provisional_steps(self) -> list[int]:
        """Steps whose record says they are provisional (an estimate that may still change)."""
        out = []
        for k, rec in sorted(self.steps.items()):
            flag = rec.get("provisional")
            if flag is True or (isinstance(flag, (list, dict)) and len(flag) > 0):
                out.append(k)
        return out


def _int(v) -> int:
    try:
        return int(v)
    except (TypeError, ValueError):
        return 0


class StreamFollower:
    """Tail the stream files of a launch's work folder or of agents run by hand.

    Parameters
    ----------
    sources : list of path
        Stream files (``NAME.jsonl`` or ``NAME.K.jsonl``: the agent's name is the file name up to the
        incarnation), or folders whose ``*.jsonl`` files are followed, new ones included.
    clock : callable
        Wall clock for ``last_seen`` (``time.time``).

    Examples
    --------
    >>> import tempfile, pathlib
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> _ = (d / "A1.0.jsonl").write_text('{"step": 0, "t": 0.0, "poses": {"A1": {"p": [1, 2, 0], "theta": 0.5}}}\\n')
    >>> f = StreamFollower([d]); f.poll()
    1
    >>> record_pose(f.agents["A1"].latest(), "A1")
    (1.0, 2.0, 0.5)
    """

    def __init__(self, sources, clock=None):
        import time

        self.sources = [Path(s) for s in sources]
        self.clock = clock or time.time
        self.agents: dict[str, AgentView] = {}
        self.bad_lines = 0
        self._offsets: dict[Path, int] = {}
        self._partial: dict[Path, bytes] = {}

    def files(self) -> list[Path]:
        out = []
        for src in self.sources:
            if src.is_dir():
                out += sorted(src.glob("*.jsonl"))
            elif src.exists():
                out.append(src)
        return out

    def poll(self) -> int:
        """Read what was appended to every stream since the last call; return the records read."""
        n = 0
        for path in self.files():
            m = _NAME.match(path.name)
            if not m:
                continue
            name, inc = m.group("name"), int(m.group("inc") or 0)
            try:
                size = os.path.getsize(path)
            except OSError:
                continue
            start = self._offsets.get(path, 0)
            if size < start:  # truncated or replaced: read it again
                start, self._partial[path] = 0, b""
            if size == start:
                continue
            with open(path, "rb") as fh:
                fh.seek(start)
                data = fh.read(min(size - start, MAX_LINE))
            self._offsets[path] = start + len(data)
            data = self._partial.pop(path, b"") + data
            lines = data.split(b"\n")
            tail = lines.pop()  # no newline yet: wait for the rest
            if len(tail) < MAX_LINE:
                self._partial[path] = tail
            view = self.agents.setdefault(name, AgentView(name))
            view.incarnations = max(view.incarnations, inc + 1)
            for line in lines:
                if not line.strip():
                    continue
                try:
                    rec = json.loads(line)
                    step = int(rec["step"])
                except (ValueError, KeyError, TypeError):
                    self.bad_lines += 1
                    continue
                if not isinstance(rec, dict):
                    self.bad_lines += 1
                    continue
                rec["_incarnation"] = inc
                old = view.steps.get(step)
                if old is None or old.get("_incarnation", 0) <= inc:
                    view.steps[step] = rec
                view.last_seen = self.clock()
                n += 1
        return n

    def assemblies(self) -> list[str]:
        """Every assembly any agent placed or named as unplaced, and every agent."""
        names = set(self.agents)
        for view in self.agents.values():
            for rec in view.steps.values():
                for key in ("poses", "unplaced"):
                    if isinstance(rec.get(key), dict):
                        names.update(str(a) for a in rec[key])
        return sorted(names)
