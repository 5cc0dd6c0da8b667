"""Reading frames for perception: image files (PNG, JPEG, ...) in time order, or one video file.

Unreadable or corrupt inputs raise :class:`decentral.errors.InputError` naming the file. Image
dimensions are read from the file's header (Pillow's lazy open) and checked against ``max_pixels``
and :data:`MIN_SIDE` before anything is decoded, video frame dimensions from the container before
the first frame is read. The decoders' own messages (libpng, libjpeg, OpenCV, FFmpeg write straight
to file descriptor 2) are silenced while they run: the caller reports one error line of its own.
"""

from __future__ import annotations

import contextlib
import os
import sys
import warnings
from pathlib import Path
from typing import Iterator, Sequence

import cv2
import numpy as np

from decentral.errors import InputError

__all__ = ["VIDEO_SUFFIXES", "MIN_SIDE", "is_video", "image_size", "load_image", "iter_frames",
           "native_stderr_silenced"]

VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".webm", ".m4v", ".mpg", ".mpeg")
#: smallest frame side, pixels: the detector's image pyramid and tag reads need at least this much
MIN_SIDE = 16


@contextlib.contextmanager
def native_stderr_silenced() -> Iterator[None]:
    """Point file descriptor 2 at /dev/null while native decoders run (Python's own stderr is flushed first)."""
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError, AttributeError):  # no real fd 2 (embedded interpreters): nothing to silence
        yield
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(devnull)


def _check_size(width: int, height: int, max_pixels: int | None, source: str) -> None:
    if width < MIN_SIDE or height < MIN_SIDE:
        raise InputError(f"image is {width} x {height} pixels; frames must be at least {MIN_SIDE} x {MIN_SIDE}",
                         source=source)
    if max_pixels is not None and width * height > max_pixels:
        raise InputError(f"image of {width} x {height} = {width * height} pixels is over the limit of {max_pixels} "
                         "pixels (set DECENTRAL_MAX_PIXELS to raise it)", source=source)


def image_size(path: str | os.PathLike) -> tuple[int, int]:
    """(width, height) of an image file from its header, without decoding the pixels."""
    from PIL import Image, UnidentifiedImageError

    bomb_limit = Image.MAX_IMAGE_PIXELS
    try:
        Image.MAX_IMAGE_PIXELS = None  # Pillow's own decompression-bomb check: the caller checks the size
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with Image.open(path) as im:
                return im.size
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError):
        raise InputError("not a readable image (corrupt or unsupported format)", source=str(path)) from None
    finally:
        Image.MAX_IMAGE_PIXELS = bomb_limit


def is_video(path: str | os.PathLike) -> bool:
    """True if ``path`` has a video file suffix."""
    return Path(path).suffix.lower() in VIDEO_SUFFIXES


def load_image(path: str | os.PathLike, max_pixels: int | None = None) -> np.ndarray:
    """Read one image as (H, W, 3) uint8 BGR; raise InputError naming ``path`` if it cannot be read.

    Its header must declare at least :data:`MIN_SIDE` pixels a side and at most ``max_pixels``
    pixels (unbounded when None) before the pixels are decoded.
    """
    p = Path(path)
    if not p.exists():
        raise InputError("file not found", source=str(path))
    if p.is_dir():
        raise InputError("is a directory, not an image", source=str(path))
    _check_size(*image_size(p), max_pixels, str(path))
    try:
        data = np.fromfile(p, dtype=np.uint8)
    except OSError as err:
        raise InputError(f"cannot read file ({err.strerror})", source=str(path)) from None
    with native_stderr_silenced():
        image = cv2.imdecode(data, cv2.IMREAD_COLOR) if data.size else None
    if image is None or image.size == 0:
        raise InputError("not a readable image (corrupt or unsupported format)", source=str(path))
    return image


def _video_frames(path: str | os.PathLike, max_pixels: int | None = None) -> Iterator[tuple[str, np.ndarray]]:
    p = Path(path)
    if not p.exists():
        raise InputError("file not found", source=str(path))
    with native_stderr_silenced():
        cap = cv2.VideoCapture(str(p))
    try:
        if not cap.isOpened():
            raise InputError("not a readable video (corrupt or unsupported format)", source=str(path))
        size = (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
        if size[0] > 0 and size[1] > 0:
            _check_size(*size, max_pixels, str(path))
        k = 0
        while True:
            with native_stderr_silenced():
                ok, image = cap.read()
            if not ok:
                break
            if k == 0:
                _check_size(image.shape[1], image.shape[0], max_pixels, str(path))
            yield f"{p.name}#{k}", image
            k += 1
        if k == 0:
            raise InputError("video holds no readable frame", source=str(path))
    finally:
        cap.release()


def iter_frames(paths: Sequence[str | os.PathLike], max_pixels: int | None = None) -> Iterator[tuple[str, np.ndarray]]:
    """Yield ``(source name, BGR image)`` in order: the frames of one video, or one per image file.

    Every path is checked to exist before the first frame is yielded; every frame's size is checked
    (at least :data:`MIN_SIDE` a side, at most ``max_pixels`` pixels) before it is decoded.
    """
    if not paths:
        raise InputError("no input frames given", field="FRAME")
    if len(paths) == 1 and is_video(paths[0]):
        yield from _video_frames(paths[0], max_pixels)
        return
    for p in paths:
        if is_video(p):
            raise InputError("a video must be the only input", source=str(p))
        if not Path(p).exists():
            raise InputError("file not found", source=str(p))
    for p in paths:
        yield str(p), load_image(p, max_pixels)
