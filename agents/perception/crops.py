"""Square crops around a circle, the second stage's input (shared by training and inference).

A crop of circle (u, v, r) is the square of side ``span * r`` centred on (u, v), resampled to
``size x size`` pixels; pixel (i, j) samples the image at
``(u, v) + (span r / size) * ((j, i) + 0.5 - size / 2)`` (OpenCV's pixel centres at integers).
Training (:mod:`agents.perception.training`) and the learned detector
(:mod:`agents.perception.learned`) build their crops with the same functions, so the network sees the
same resampling in both.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["CROP_SIZE", "CROP_SPAN", "REFINE_SIZE", "REFINE_SPAN", "crop_circle", "refine_input"]

#: width of a stored crop in radii, and its side in pixels
CROP_SPAN = 4.0
CROP_SIZE = 64
#: width of the second stage's input window in radii of the proposal, and its side in pixels
REFINE_SPAN = 2.5
REFINE_SIZE = 32


def crop_circle(image: np.ndarray, u: float, v: float, r: float, size: int = CROP_SIZE,
                span: float = CROP_SPAN) -> np.ndarray:
    """The square of side ``span * r`` centred on (u, v), resampled to (size, size, 3) uint8 (border replicated)."""
    s = span * r / size
    m = np.array([[s, 0.0, u - s * (size / 2.0 - 0.5)], [0.0, s, v - s * (size / 2.0 - 0.5)]], np.float64)
    return cv2.warpAffine(image, m, (size, size), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                          borderMode=cv2.BORDER_REPLICATE)


def refine_input(crop: np.ndarray, du: float = 0.0, dv: float = 0.0, scale: float = 1.0) -> np.ndarray:
    """The second stage's (REFINE_SIZE, REFINE_SIZE, 3) window taken from a stored crop.

    ``crop`` is :func:`crop_circle` of a circle (u, v, r); the window is centred on
    (u + du r, v + dv r) and is ``REFINE_SPAN * scale * r`` wide, i.e. the input for a proposal
    (u + du r, v + dv r, scale r).
    """
    c = crop.shape[0]
    px = c / CROP_SPAN  # crop pixels per radius
    s = REFINE_SPAN * scale * px / REFINE_SIZE
    cx, cy = c / 2.0 - 0.5 + du * px, c / 2.0 - 0.5 + dv * px
    m = np.array([[s, 0.0, cx - s * (REFINE_SIZE / 2.0 - 0.5)], [0.0, s, cy - s * (REFINE_SIZE / 2.0 - 0.5)]])
    return cv2.warpAffine(crop, m, (REFINE_SIZE, REFINE_SIZE), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                          borderMode=cv2.BORDER_REPLICATE)
