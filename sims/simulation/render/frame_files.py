"""Writing a simulated run's camera frames: PNG files or one video per camera.

PNG frames go to ``OUTDIR/frames/<assembly>/<camera>/<step:05d>.png``; a video to
``OUTDIR/frames/<assembly>/<camera>.mp4`` (MPEG-4 part 2, or ``.avi`` Motion-JPEG where no MP4
encoder is available). Each file is written whole or not at all.
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from decentral.errors import InputError
from sims.io.atomic import write_atomic
from sims.simulation.render.renderer import RenderConfig, Renderer
from sims.simulation.scenarios.base import Simulation
from sims.simulation.world.sensors import sensor_streams

__all__ = ["render_frames", "write_frames"]


def render_frames(sim: Simulation, seed: int, config: RenderConfig):
    """Yield ``(step, camera key, Frame)`` for every step and camera of ``sim``.

    The floor texture comes from the stream ``render/floor`` and each camera's effects from
    ``render/<camera key>``, children of ``seed`` (see :func:`sims.simulation.world.sensors.sensor_streams`).
    """
    keys = [rig.key for rig in sim.world.cameras]
    streams = sensor_streams(seed, ["render/floor"] + [f"render/{k}" for k in keys])
    renderer = Renderer(sim.world, config, streams["render/floor"])
    for k in range(sim.world.steps):
        for rig in sim.world.cameras:
            yield k, rig.key, renderer.render(rig, k, streams[f"render/{rig.key}"])


def _write_png(path: Path, image: np.ndarray) -> None:
    ok, data = cv2.imencode(".png", image)
    if not ok:  # pragma: no cover - OpenCV always encodes uint8 BGR
        raise InputError("PNG encoding failed", source=str(path))
    write_atomic(path, lambda fh: fh.write(data.tobytes()), binary=True)


def _open_video(path_stem: Path, fps: float, size: tuple[int, int]):
    for suffix, fourcc in ((".mp4", "mp4v"), (".avi", "MJPG")):
        tmp = path_stem.with_name(f".{path_stem.name}{suffix}.part{suffix}")
        writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*fourcc), fps, size)
        if writer.isOpened():
            return writer, tmp, path_stem.with_suffix(suffix)
        writer.release()
    raise InputError("no video encoder available (tried MP4 and MJPG AVI)", field="--frames")


def write_frames(sim: Simulation, outdir: str | os.PathLike, *, mode: str = "png", seed: int = 0,
                 config: RenderConfig | None = None, progress=None) -> tuple[list[Path], tuple]:
    """Render every camera's frames into ``outdir/frames`` and return (paths, per-step frame truth).

    Parameters
    ----------
    mode : {"png", "video"}
    config : RenderConfig, optional
        Defaults to :class:`RenderConfig` for a noisy run and :meth:`RenderConfig.clean` when the
        scenario's sensors are noiseless.
    progress : callable, optional
        Called after each frame as ``progress(frames_done, frames_total)``.

    Returns
    -------
    paths : list[Path]
        The files written.
    frames : tuple[dict, ...]
        Per step, camera key -> ``{"file": ..., "nodes": [...]}`` (see :class:`~sims.simulation.render.renderer.Frame`).
    """
    if mode not in ("png", "video"):
        raise InputError(f"unknown frame mode {mode!r} (png or video)", field="--frames")
    if config is None:
        noisy = sim.truth.meta.get("config", {}).get("noise", True)
        config = RenderConfig() if noisy else RenderConfig.clean()
    root = Path(outdir) / "frames"
    dt = float(np.median(np.diff(sim.world.times))) if sim.world.steps > 1 else 0.2
    writers, paths = {}, []
    frames: list[dict] = [dict() for _ in range(sim.world.steps)]
    total, done = sim.world.steps * len(sim.log.cameras), 0
    try:
        for k, key, frame in render_frames(sim, seed, config):
            if mode == "png":
                path = root / key / f"{k:05d}.png"
                path.parent.mkdir(parents=True, exist_ok=True)
                _write_png(path, frame.image)
                paths.append(path)
                name = path.relative_to(outdir).as_posix()
            else:
                if key not in writers:
                    stem = root / key
                    stem.parent.mkdir(parents=True, exist_ok=True)
                    h, w = frame.image.shape[:2]
                    writers[key] = _open_video(stem, 1.0 / dt, (w, h))
                writers[key][0].write(frame.image)
                name = f"{writers[key][2].relative_to(outdir).as_posix()}#{k}"
            frames[k][key] = {"file": name, "nodes": frame.nodes}
            done += 1
            if progress is not None:
                progress(done, total)
        for writer, tmp, final in writers.values():
            writer.release()
            os.replace(tmp, final)
            paths.append(final)
        writers = {}
    finally:
        for writer, tmp, _ in writers.values():
            writer.release()
            if tmp.exists():
                tmp.unlink()
    return paths, tuple(frames)
