"""Floors and backgrounds of several kinds, and the scene-wide lighting gradient.

What a robot's camera sees behind its nodes varies: a textured grey lab floor, tiles with grout
lines, wooden planks, carpet, speckled concrete, a wall above the floor. Each generator returns a
reflectance image (H, W, 3) float32 BGR in [0, 1] drawn from ``rng``; :func:`lighting_gradient` is
the smooth illumination change across the frame (a linear ramp and vignetting) that multiplies
everything in it.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["SURFACES", "surface", "lighting_gradient"]


def _smooth_noise(rng: np.random.Generator, height: int, width: int, cell: float) -> np.ndarray:
    """Zero-mean smooth noise (H, W) float32 of unit-ish amplitude varying over ``cell`` pixels."""
    gh, gw = max(int(height / cell), 1) + 2, max(int(width / cell), 1) + 2
    small = rng.standard_normal((gh, gw)).astype(np.float32)
    return cv2.resize(small, (width, height), interpolation=cv2.INTER_CUBIC)


def _grain(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    """Multi-scale grain (H, W): blotches of ~100 px, mottling of ~20 px and pixel grain."""
    fine = cv2.GaussianBlur(rng.standard_normal((height, width)).astype(np.float32), (0, 0), 0.8)
    return 0.5 * _smooth_noise(rng, height, width, 110) + 0.35 * _smooth_noise(rng, height, width, 18) + 0.4 * fine


def _tint(rng: np.random.Generator, base: float, spread: float) -> np.ndarray:
    """A BGR colour of mean ``base`` with channels differing by up to ``spread``."""
    return np.clip(base + rng.uniform(-spread, spread, 3), 0.05, 0.95).astype(np.float32)


def grey_grain(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    """A textured grey floor (lab vinyl or painted concrete): grey with blotches and grain."""
    tone = 1.0 + 0.09 * _grain(rng, height, width)
    return _tint(rng, rng.uniform(0.3, 0.65), 0.03)[None, None, :] * tone[:, :, None]


def tiles(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    """Square tiles of two tones with darker grout lines, seen at a random rotation."""
    size = rng.uniform(60.0, 220.0)
    angle = rng.uniform(0.0, np.pi / 2)
    v, u = np.mgrid[0:height, 0:width].astype(np.float32)
    a = (u * np.cos(angle) + v * np.sin(angle)) / size
    b = (-u * np.sin(angle) + v * np.cos(angle)) / size
    checker = ((np.floor(a) + np.floor(b)) % 2).astype(np.float32)
    grout = np.minimum(np.abs(a - np.round(a)), np.abs(b - np.round(b))) * size < rng.uniform(1.0, 2.5)
    c0, c1 = _tint(rng, rng.uniform(0.3, 0.7), 0.08), _tint(rng, rng.uniform(0.3, 0.7), 0.08)
    tex = c0[None, None, :] * (1 - checker)[:, :, None] + c1[None, None, :] * checker[:, :, None]
    tex *= (1.0 + 0.05 * _grain(rng, height, width))[:, :, None]
    tex[grout] *= 0.6
    return tex


def wood(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    """Wooden planks: bands of random width and tone with grain streaks along them."""
    edges = np.cumsum(rng.uniform(40.0, 110.0, size=64))
    v = np.arange(height, dtype=np.float32)
    plank = np.searchsorted(edges, v)
    tone = rng.uniform(0.8, 1.15, size=len(edges) + 1).astype(np.float32)[plank]
    streaks = cv2.resize(rng.standard_normal((height, max(width // 60, 2))).astype(np.float32), (width, height),
                         interpolation=cv2.INTER_CUBIC)
    gaps = (np.abs(v[:, None] - edges[np.clip(plank, 0, len(edges) - 1)][:, None]) < 1.5).astype(np.float32)
    shade = tone[:, None] * (1.0 + 0.07 * streaks) * (1.0 - 0.35 * gaps)
    base = np.array([0.25, 0.42, 0.58], np.float32) * rng.uniform(0.75, 1.15)  # BGR: brown
    return base[None, None, :] * shade[:, :, None]


def carpet(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    """Carpet: strong pixel-scale coloured noise over a uniform colour."""
    noise = cv2.GaussianBlur(rng.standard_normal((height, width, 3)).astype(np.float32), (0, 0), 0.9)
    return _tint(rng, rng.uniform(0.25, 0.55), 0.12)[None, None, :] * (1.0 + 0.22 * noise + 0.05 * _smooth_noise(
        rng, height, width, 80)[:, :, None])


def concrete(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    """Speckled concrete with a few dark cracks."""
    tex = grey_grain(rng, height, width)
    speck = rng.random((height, width)) < 0.004
    tex[speck] *= 0.55
    for _ in range(int(rng.integers(1, 5))):
        pts = np.cumsum(rng.normal(0.0, 25.0, size=(12, 2)), axis=0) + rng.uniform([0, 0], [width, height])
        cv2.polylines(tex, [pts.astype(np.int32)], False, tuple(float(x) for x in 0.6 * tex.mean(axis=(0, 1))), 1,
                      cv2.LINE_AA)
    return tex


def wall_and_floor(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    """A plain wall above a floor of another kind, meeting at a horizon line across the frame."""
    floor = FLOORS[int(rng.integers(0, len(FLOORS)))](rng, height, width)
    wall = _tint(rng, rng.uniform(0.5, 0.85), 0.05)[None, None, :] * (1.0 + 0.03 * _grain(rng, height, width))[:, :, None]
    horizon = rng.uniform(0.12, 0.4) * height + np.arange(width) * np.tan(rng.uniform(-0.08, 0.08))
    above = np.arange(height)[:, None] < horizon[None, :]
    return np.where(above[:, :, None], wall, floor)


FLOORS = (grey_grain, tiles, wood, carpet, concrete)
#: name -> generator ``(rng, height, width) -> (H, W, 3) float32`` reflectance
SURFACES = {f.__name__: f for f in (*FLOORS, wall_and_floor)}


def surface(kind: str, rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    """The reflectance image (H, W, 3) float32 in [0, 1] of surface ``kind`` (a key of :data:`SURFACES`)."""
    if kind not in SURFACES:
        raise ValueError(f"unknown surface {kind!r}; expected one of {sorted(SURFACES)}")
    return np.clip(SURFACES[kind](rng, height, width), 0.0, 1.0).astype(np.float32)


def lighting_gradient(rng: np.random.Generator, height: int, width: int, strength: float = 0.35) -> np.ndarray:
    """Illumination factor (H, W) float32 around 1: a random linear ramp plus vignetting.

    ``strength`` is the largest relative change of the ramp across the frame; the vignette darkens
    the corners by up to a quarter.
    """
    v, u = np.mgrid[0:height, 0:width].astype(np.float32)
    x, y = (u - width / 2) / width, (v - height / 2) / height
    angle = rng.uniform(0, 2 * np.pi)
    ramp = 1.0 + rng.uniform(0.0, strength) * (x * np.cos(angle) + y * np.sin(angle)) * 2.0
    vignette = 1.0 - rng.uniform(0.0, 0.25) * (x * x + y * y) * 2.0
    return (ramp * vignette).astype(np.float32)
