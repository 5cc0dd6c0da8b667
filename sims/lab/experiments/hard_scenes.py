"""Harder varied scenes for training the learned circle detector.

:func:`sequence` of :mod:`sims.lab.experiments.varied_scenes` draws spheres of 15-90 px spread over
the frame on one of six floors. A robot's camera also sees nodes close to it (large, often cut by
the frame's edge), nodes far away (12-24 px), nodes of an assembly in a clump that hide one another, floors that are neither of
those six (a rug on tiles, a coarse or fine version of a texture, a tinted one) and light that is
dim, harsh or uneven. :func:`hard_sequence` draws such scenes with the same renderer
(:func:`~sims.lab.experiments.varied_scenes.render`) and the same exact truth, from one seed. Its
draws are its own: the varied scenes, held-out ones included, are unchanged by it.
:func:`pair_sequence` draws, on the same floors and light, small spheres in touching or overlapping
groups of two or three (an assembly's nodes seen from afar).
"""

from __future__ import annotations

import cv2
import numpy as np

from sims.lab.experiments.varied_scenes import (Frame, animate, random_look, random_mover, random_struts,
                                                random_tag_normal)
from sims.simulation.render.surfaces import SURFACES, lighting_gradient, surface
from sims.simulation.render.textures import TAG_IDS

__all__ = ["hard_floor", "hard_sequence", "overlap_sequence", "pair_sequence"]


def hard_floor(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    """A floor (H, W, 3) float32 in [0, 1]: one of the surfaces, rescaled, tinted, sometimes patched with another.

    The texture is drawn at 0.5-2 times the frame's size and resized to it (coarser or finer
    grain, tiles and planks), its channels scaled by up to 25 % each (tinted floors), and with
    probability 0.4 a second surface shows through a smooth blob-shaped mask (a rug, a stain, a
    patch of another floor).
    """
    kinds = list(SURFACES)

    def one() -> np.ndarray:
        zoom = float(np.exp(rng.uniform(np.log(0.5), np.log(2.0))))
        hh, ww = max(int(height / zoom), 16), max(int(width / zoom), 16)
        tex = surface(kinds[int(rng.integers(0, len(kinds)))], rng, hh, ww)
        tex = cv2.resize(tex, (width, height), interpolation=cv2.INTER_LINEAR if zoom > 1 else cv2.INTER_AREA)
        return tex * rng.uniform(0.75, 1.25, 3).astype(np.float32)[None, None, :]

    floor = one()
    if rng.random() < 0.4:
        other = one()
        blob = cv2.resize(rng.standard_normal((4, 5)).astype(np.float32), (width, height),
                          interpolation=cv2.INTER_CUBIC)
        mask = (blob > rng.uniform(-0.3, 0.8)).astype(np.float32)
        mask = cv2.GaussianBlur(mask, (0, 0), rng.uniform(0.6, 4.0))[:, :, None]
        floor = floor * (1 - mask) + other * mask
    return np.clip(floor, 0.0, 1.0).astype(np.float32)


def _colour(rng: np.random.Generator, floor_mean: np.ndarray) -> tuple[float, float, float]:
    if rng.random() < 0.4:  # close to the floor's colour
        c = floor_mean + rng.uniform(-0.07, 0.07, 3)
    else:
        c = rng.uniform(0.08, 0.92, 3)
    return tuple(float(x) for x in np.clip(c, 0.04, 0.96))


def _place(rng: np.random.Generator, r: float, width: int, height: int, mode: str,
           anchor: np.ndarray) -> np.ndarray:
    """A centre for a sphere of radius ``r``: anywhere, cut by an edge, or beside ``anchor`` (a clump)."""
    if mode == "edge":  # its centre within 0.5 r outside to 0.7 r inside one edge
        u, v = rng.uniform(0, width), rng.uniform(0, height)
        side = int(rng.integers(0, 4))
        d = rng.uniform(-0.5, 0.7) * r
        if side == 0:
            u = d
        elif side == 1:
            u = width - 1 - d
        elif side == 2:
            v = d
        else:
            v = height - 1 - d
        return np.array([u, v])
    if mode == "clump":  # overlapping or touching a neighbour of the clump
        ang = rng.uniform(0, 2 * np.pi)
        dist = rng.uniform(0.5, 1.3) * (r + rng.uniform(15, 80))
        return anchor + dist * np.array([np.cos(ang), np.sin(ang)])
    return rng.uniform([r, r], [width - r, height - r])


def hard_sequence(seed: int, frames: int = 10, *, width: int = 1024, height: int = 768,
                  radius: tuple[float, float] = (12.0, 110.0)) -> list[Frame]:
    """A harder sequence of ``frames`` frames from ``seed`` (see the module's text).

    Per scene: a floor of :func:`hard_floor`, a lighting gradient of strength 0.2-0.7, wide
    lighting and camera ranges, 3-14 spheres, 0-4 struts. Each sphere is one of: *near* (radius
    log-uniform in the upper half of ``radius``), *far* (radius from the smallest to twice that), *edge* (centre within half a radius outside to
    0.7 r inside a frame edge), *clump* (beside the scene's clump centre, overlapping its
    neighbours), or *free* (log-uniform radius anywhere). Per frame: smooth motion, sizes changing by
    up to 15 %, turning tags, smear now and then; spheres may drift out of the frame by up to one
    radius.
    """
    rng, noise_rng, motion_rng, floor, gradient, look, floor_mean = _setting(seed, 7, width, height)
    n = int(rng.integers(3, 15))
    ids = rng.choice(TAG_IDS, size=n, replace=False)
    clump = rng.uniform([0.2 * width, 0.2 * height], [0.8 * width, 0.8 * height])
    lo, hi = np.log(radius[0]), np.log(radius[1])
    movers = []
    for i in range(n):
        mode = str(rng.choice(["near", "far", "edge", "clump", "free"], p=[0.15, 0.25, 0.2, 0.25, 0.15]))
        if mode == "far":  # small: a node far away
            r = float(np.exp(rng.uniform(lo, np.log(2.0 * radius[0]))))
        elif mode in ("near", "edge") and rng.random() < 0.7:
            r = float(np.exp(rng.uniform(0.5 * (lo + hi), hi)))
        else:
            r = float(np.exp(rng.uniform(lo, hi)))
        u, v = _place(rng, r, width, height, mode, clump)
        normal = random_tag_normal(rng, 1.3)
        colour = _colour(rng, floor_mean)
        movers.append(random_mover(rng, int(ids[i]), float(u), float(v), r, colour, tag=bool(rng.random() < 0.9),
                                   tag_normal=normal, max_specular=0.8, speed=3.0 if mode != "clump" else 1.5))
    return _animate(rng, movers, look, floor, gradient, noise_rng, motion_rng, frames, radius, width, height)


def _setting(seed: int, salt: int, width: int, height: int):
    """A scene's generators (draws, sensor noise, motion), floor, lighting gradient, look and the floor's
    mean colour, from ``seed`` and the generator's own ``salt``."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, salt]))
    floor_rng, noise_rng, motion_rng = (np.random.default_rng(s) for s in np.random.SeedSequence([seed, salt]).spawn(3))
    floor = hard_floor(floor_rng, height, width)
    gradient = lighting_gradient(floor_rng, height, width, strength=float(rng.uniform(0.2, 0.7)))
    look = random_look(rng, elevation=(0.25, 1.3), ambient=(0.15, 0.6), noise=(1.0, 9.0), blur=(0.0, 1.5),
                       gain=(0.55, 1.35), jpeg=(0, 0, 50, 70, 85), shadow=(0.05, 0.45))  # dim to harsh
    return rng, noise_rng, motion_rng, floor, gradient, look, floor.reshape(-1, 3).mean(axis=0)


def _animate(rng, movers, look, floor, gradient, noise_rng, motion_rng, frames: int, radius, width: int, height: int):
    """The frames of ``movers`` with 0-4 struts over them (the harder scenes' motion and sensor)."""
    struts = random_struts(rng, width, height, count=(0, 4), spread=220, widths=(4, 20), greys=(0.1, 0.85))
    return animate(movers, struts, look, floor, gradient, noise_rng, motion_rng, frames,
                   radius=radius, jitter=1.0, wobble=0.15, margin=1.0)


def pair_sequence(seed: int, frames: int = 10, *, width: int = 1024, height: int = 768,
                  radius: tuple[float, float] = (12.0, 45.0),
                  ratio: tuple[float, float] = (0.75, 1.33)) -> list[Frame]:
    """Small spheres in touching or overlapping groups of two or three: ``frames`` frames from ``seed``.

    Floors, light and sensor as :func:`hard_sequence` (draws of their own). 2-5 groups; a group's first
    sphere has a log-uniform radius in ``radius``, each next one ``ratio`` times its predecessor's
    (log-uniform, clipped to ``radius``), its centre 0.6-1.1 times the two radii's sum away in any
    direction (one hides part of the other, or they touch: two nodes of an assembly seen from afar, which a
    proposal network tends to take for one larger circle); plus 0-3 lone spheres of 12-110 px. Groups move
    slowly, so they stay together. (:func:`overlap_sequence`: larger spheres of unequal sizes.)
    """
    rng, noise_rng, motion_rng, floor, gradient, look, floor_mean = _setting(seed, 11, width, height)
    groups = int(rng.integers(2, 6))
    sizes = [int(rng.integers(2, 4)) for _ in range(groups)]
    lone = int(rng.integers(0, 4))
    ids = rng.choice(TAG_IDS, size=sum(sizes) + lone, replace=False)
    lo, hi = np.log(radius[0]), np.log(radius[1])
    movers = []

    def add(u: float, v: float, r: float, speed: float) -> None:
        movers.append(random_mover(rng, int(ids[len(movers)]), float(u), float(v), r, _colour(rng, floor_mean),
                                   tag=bool(rng.random() < 0.9), tag_normal=random_tag_normal(rng, 1.3),
                                   max_specular=0.8, speed=speed))

    for size in sizes:
        r = float(np.exp(rng.uniform(lo, hi)))
        at = rng.uniform([4 * r, 4 * r], [width - 4 * r, height - 4 * r])
        add(*at, r, 1.0)
        for _ in range(size - 1):
            r2 = float(np.clip(r * np.exp(rng.uniform(np.log(ratio[0]), np.log(ratio[1]))), radius[0], radius[1]))
            ang = rng.uniform(0, 2 * np.pi)
            at = at + rng.uniform(0.6, 1.1) * (r + r2) * np.array([np.cos(ang), np.sin(ang)])
            add(*at, r2, 1.0)
            r = r2
    for _ in range(lone):
        r = float(np.exp(rng.uniform(np.log(12.0), np.log(110.0))))
        add(*rng.uniform([r, r], [width - r, height - r]), r, 3.0)
    return _animate(rng, movers, look, floor, gradient, noise_rng, motion_rng, frames, (12.0, 110.0), width, height)


def overlap_sequence(seed: int, frames: int = 10, *, width: int = 1024, height: int = 768) -> list[Frame]:
    """Groups of spheres of unequal sizes, 20-90 px, each next one 0.55-1.8 times its predecessor: a large
    sphere partly hidden behind a smaller, nearer one (or the other way round), which a network taught to
    split small touching spheres (:func:`pair_sequence`) tends to leave out. ``frames`` frames from ``seed``;
    otherwise as :func:`pair_sequence`."""
    return pair_sequence(seed, frames, width=width, height=height, radius=(20.0, 90.0), ratio=(0.55, 1.8))
