"""Saving a simulated run: ``log.json`` (``decentral.log/1``), ``truth.json`` (``decentral.truth/1``), frames."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from decentral.errors import InputError
from sims.simulation.scenarios.base import Simulation

__all__ = ["SavedRun", "prepare_outdir", "save_simulation"]


@dataclass(frozen=True)
class SavedRun:
    """Paths written for one run."""

    log: Path
    truth: Path
    frames: tuple[Path, ...] = ()


def prepare_outdir(outdir: str | os.PathLike) -> Path:
    """Create ``outdir`` (and parents) if needed; refuse a path that exists and is not a folder."""
    path = Path(outdir)
    if path.exists() and not path.is_dir():
        raise InputError("exists and is not a folder", source=str(path))
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise InputError(f"cannot create output folder ({err.strerror})", source=str(path)) from None
    return path


def save_simulation(sim: Simulation, outdir: str | os.PathLike, *, frames: str = "none", seed: int = 0,
                    progress=None) -> SavedRun:
    """Write ``sim``'s log and truth (and its frames) into ``outdir``; each file atomically.

    ``frames`` is ``"none"``, ``"png"`` or ``"video"``; with frames, the truth also records what
    each frame shows (see :mod:`sims.simulation.world.truth`), and the frames are rendered with ``seed``
    (``progress(frames_done, frames_total)`` is called after each).
    """
    from dataclasses import replace

    from sims.io.log_json import write_log
    from sims.simulation.world.truth import write_truth

    if frames not in ("none", "png", "video"):
        raise InputError(f"unknown frame mode {frames!r} (png, video or none)", field="--frames")
    path = prepare_outdir(outdir)
    truth, written = sim.truth, ()
    if frames != "none":
        from sims.simulation.render.frame_files import write_frames

        files, per_step = write_frames(sim, path, mode=frames, seed=seed, progress=progress)
        truth, written = replace(truth, frames=per_step), tuple(files)
    write_log(path / "log.json", sim.log)
    write_truth(path / "truth.json", truth)
    return SavedRun(path / "log.json", path / "truth.json", written)
