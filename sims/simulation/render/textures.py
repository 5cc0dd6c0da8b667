"""Textures of the rendered scene: AprilTag 36h11 stickers and a floor.

Tag bitmaps come from OpenCV's ``DICT_APRILTAG_36h11`` (``generateImageMarker`` with a one-cell
black border: 8 x 8 cells, ids 0-586).
"""

from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np

__all__ = ["TAG_IDS", "tag_cells", "floor_texture"]

#: number of ids in the 36h11 family
TAG_IDS = 587


@lru_cache(maxsize=1024)
def tag_cells(tag_id: int) -> np.ndarray | None:
    """The 8 x 8 cell bitmap (bool, True = white) of 36h11 tag ``tag_id``, or ``None`` outside 0-586."""
    if not 0 <= tag_id < TAG_IDS:
        return None
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
    cells = cv2.aruco.generateImageMarker(dictionary, int(tag_id), 8, borderBits=1) > 127
    cells.setflags(write=False)
    return cells


def floor_texture(rng: np.random.Generator, size: int = 2048, metres: float = 16.0, tile: float = 0.5) -> np.ndarray:
    """A floor texture (size, size, 3) float32 in [0, 1] covering ``metres`` x ``metres``.

    Two-tone tiles of ``tile`` metres with multi-scale grain, so the floor has texture everywhere
    (the ESP32-CAM-like frames must not be trivially clean outside the robots).
    """
    px = size / metres
    ij = np.arange(size) / px
    checker = ((np.floor(ij[:, None] / tile) + np.floor(ij[None, :] / tile)) % 2).astype(np.float32)
    grain = np.zeros((size, size), np.float32)
    for cells, weight in ((8, 0.5), (64, 0.3), (512, 0.2)):
        small = rng.standard_normal((cells, cells)).astype(np.float32)
        grain += weight * cv2.resize(small, (size, size), interpolation=cv2.INTER_CUBIC)
    base = np.array([0.42, 0.47, 0.52], np.float32)  # BGR: a warm grey-brown floor
    tone = 0.85 + 0.15 * checker + 0.05 * grain
    tex = base[None, None, :] * tone[:, :, None]
    lines = (np.abs((ij / tile) - np.round(ij / tile)) * tile * px < 1.0).astype(np.float32)
    tex *= 1.0 - 0.25 * np.maximum(lines[:, None], lines[None, :])[:, :, None]
    return np.clip(tex, 0.0, 1.0)
