"""Reading frames for perception: image files (PNG, JPEG, ...) in time order, or one video file.

Unreadable or corrupt inputs raise :class:`decentral.errors.InputError` naming the file.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Iterator, Sequence

import cv2
import numpy as np

from decentral.errors import InputError

__all__ = ["VIDEO_SUFFIXES", "is_video", "load_image", "iter_frames"]

VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".webm", ".m4v", ".mpg", ".mpeg")


def is_video(path: str | os.PathLike) -> bool:
    """True if ``path`` has a video file suffix."""
    return Path(path).suffix.lower() in VIDEO_SUFFIXES


def load_image(path: str | os.PathLike) -> np.ndarray:
    """Read one image as (H, W, 3) uint8 BGR; raise InputError naming ``path`` if it cannot be read."""
    p = Path(path)
    if not p.exists():
        raise InputError("file not found", source=str(path))
    if p.is_dir():
        raise InputError("is a directory, not an image", source=str(path))
    try:
        data = np.fromfile(p, dtype=np.uint8)
    except OSError as err:
        raise InputError(f"cannot read file ({err.strerror})", source=str(path)) from None
    image = cv2.imdecode(data, cv2.IMREAD_COLOR) if data.size else None
    if image is None or image.size == 0:
        raise InputError("not a readable image (corrupt or unsupported format)", source=str(path))
    return image


def _video_frames(path: str | os.PathLike) -> Iterator[tuple[str, np.ndarray]]:
    p = Path(path)
    if not p.exists():
        raise InputError("file not found", source=str(path))
    cap = cv2.VideoCapture(str(p))
    try:
        if not cap.isOpened():
            raise InputError("not a readable video (corrupt or unsupported format)", source=str(path))
        k = 0
        while True:
            ok, image = cap.read()
            if not ok:
                break
            yield f"{p.name}#{k}", image
            k += 1
        if k == 0:
            raise InputError("video holds no readable frame", source=str(path))
    finally:
        cap.release()


def iter_frames(paths: Sequence[str | os.PathLike]) -> Iterator[tuple[str, np.ndarray]]:
    """Yield ``(source name, BGR image)`` in order: the frames of one video, or one per image file.

    Every path is checked to exist before the first frame is yielded.
    """
    if not paths:
        raise InputError("no input frames given", field="FRAME")
    if len(paths) == 1 and is_video(paths[0]):
        yield from _video_frames(paths[0])
        return
    for p in paths:
        if is_video(p):
            raise InputError("a video must be the only input", source=str(p))
        if not Path(p).exists():
            raise InputError("file not found", source=str(p))
    for p in paths:
        yield str(p), load_image(p)
