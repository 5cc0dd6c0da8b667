"""Camera effects applied to a rendered frame: exposure, motion blur, optical blur, sensor noise, JPEG."""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["motion_kernel", "apply_effects"]


def motion_kernel(dx: float, dy: float) -> np.ndarray | None:
    """A normalized line kernel for an image motion of (dx, dy) px during the exposure (None if < 1 px)."""
    length = float(np.hypot(dx, dy))
    if length < 1.0:
        return None
    size = int(np.ceil(length)) | 1
    size = max(size, 3)
    kernel = np.zeros((size, size), np.float32)
    c = size // 2
    n = max(int(np.ceil(length)) * 4, 2)
    for s in np.linspace(-0.5, 0.5, n):
        x, y = c + s * dx, c + s * dy
        kernel[int(round(y)), int(round(x))] += 1.0
    return kernel / kernel.sum()


def apply_effects(
    image: np.ndarray,
    rng: np.random.Generator,
    *,
    gain: float = 1.0,
    motion: tuple[float, float] = (0.0, 0.0),
    blur_sigma: float = 0.0,
    noise_sigma: float = 0.0,
    jpeg_quality: int = 0,
    noise_pool: np.ndarray | None = None,
) -> np.ndarray:
    """Turn a float image (H, W, 3) in [0, 1] (display intensities) into an 8-bit BGR frame.

    Parameters
    ----------
    gain : float
        Exposure multiplier (1: nominal).
    motion : (dx, dy)
        Image motion [px] during the exposure; blurs along it.
    blur_sigma : float
        Gaussian optical blur [px].
    noise_sigma : float
        Std of additive Gaussian sensor noise, in 8-bit grey levels.
    jpeg_quality : int
        Re-encode as JPEG at this quality (0: off), like the ESP32-CAM's stream.
    noise_pool : ndarray, optional
        Standard normal float32 samples (at least ``image.size`` of them); each frame then uses a
        window of the pool at a random offset (from ``rng``) instead of drawing every sample anew,
        which is several times faster for the same per-pixel statistics.
    """
    img = image
    kernel = motion_kernel(*motion)
    if kernel is not None:
        img = cv2.filter2D(img, -1, kernel, borderType=cv2.BORDER_REPLICATE)
    if blur_sigma > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur_sigma)
    img = img * np.float32(255.0 * gain)
    if noise_sigma > 0:
        n = img.size
        if noise_pool is not None and noise_pool.size >= n:
            start = int(rng.integers(0, noise_pool.size - n + 1))
            noise = noise_pool[start:start + n].reshape(img.shape)
        else:
            noise = rng.standard_normal(img.shape, dtype=np.float32)
        img += noise * np.float32(noise_sigma)
    out = np.clip(img, 0, 255).astype(np.uint8)
    if jpeg_quality:
        ok, data = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)])
        if ok:
            out = cv2.imdecode(data, cv2.IMREAD_COLOR)
    return out
