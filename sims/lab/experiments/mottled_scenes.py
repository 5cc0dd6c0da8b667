"""Mottled floors: tagged discs on smooth random blotches, at many blotch sizes, contrasts and tints.

Carpet, terrazzo, stained concrete and gravel look, to a circle detector, like a field of soft round
blobs. The varied scenes (:mod:`sims.lab.experiments.varied_scenes`) have no such floor, and a
network trained on them alone proposed about 28 circles a 1024 x 768 frame on the perception tests'
blotchy floor (:func:`sims.lab.experiments.synthetic_scene.floor_texture`) where hough proposed none.
:func:`mottled_frames` draws frames of this kind with :func:`~sims.lab.experiments.synthetic_scene.draw_scene`
(shaded discs, an AprilTag 36h11 on most, struts, blur, noise) on floors whose blotches are 6-48 px
across, each frame from one seed, with the exact circle and visible fraction of every disc; a
quarter of the frames hold no disc at all (pure floor).

Seeds: :data:`HELD_OUT_MOTTLED_SEEDS` are for evaluation only (the training data refuses them).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from sims.lab.experiments.synthetic_scene import Bar, SceneConfig, SceneNode, draw_scene, visible_fraction

__all__ = ["HELD_OUT_MOTTLED_SEEDS", "Disc", "MottledFrame", "mottled_floor", "mottled_frames"]

#: mottled scenes kept out of training, for measuring false circles on floors of this kind
HELD_OUT_MOTTLED_SEEDS = tuple(range(7000, 7016))


@dataclass(frozen=True)
class Disc:
    """One disc's truth as the perception scores read it (:mod:`sims.lab.experiments.perception_scores`):
    ``id`` its index in the frame, circle ``(u, v, r)`` in pixels."""

    id: int
    u: float
    v: float
    r: float


@dataclass(frozen=True)
class MottledFrame:
    """A frame and its truth: ``image`` (H, W, 3) uint8 BGR; ``circles`` (n, 3) u, v, r in pixels (OpenCV's
    pixel centres); ``visible`` (n,) the fraction of each disc inside the image and not behind a larger one."""

    image: np.ndarray
    circles: np.ndarray
    visible: np.ndarray

    @property
    def spheres(self) -> tuple[Disc, ...]:
        """The discs as :func:`sims.lab.experiments.perception_scores.score_frame` reads a frame's spheres."""
        return tuple(Disc(i, *map(float, c)) for i, c in enumerate(self.circles))


def mottled_floor(width: int, height: int, rng: np.random.Generator) -> np.ndarray:
    """A smooth random floor, (height, width) float32 grey levels: blotches ``cell`` = 6-48 px across around a
    mean of 60-170 with a contrast of 15-70 levels, plus fine grain of 0-25 levels."""
    cell = float(np.exp(rng.uniform(np.log(6.0), np.log(48.0))))
    gh, gw = int(np.ceil(height / cell)) + 2, int(np.ceil(width / cell)) + 2
    coarse = rng.uniform(0.0, 1.0, size=(gh, gw)).astype(np.float32)
    tex = cv2.resize(coarse, (int(gw * cell), int(gh * cell)), interpolation=cv2.INTER_CUBIC)[:height, :width]
    fine = cv2.GaussianBlur(rng.uniform(0, 1, size=(height, width)).astype(np.float32), (0, 0), rng.uniform(0.7, 2.0))
    mean, contrast, grain = rng.uniform(60, 170), rng.uniform(15, 70), rng.uniform(0, 25)
    return (mean + contrast * (np.clip(tex, 0, 1) - 0.5) + grain * (fine - 0.5)).astype(np.float32)


def _discs(rng: np.random.Generator, width: int, height: int) -> list[SceneNode]:
    """0-8 discs of 12-90 px radius (none in a quarter of the frames), most with a tag; they may overlap."""
    if rng.random() < 0.25:
        return []
    nodes = []
    for _ in range(int(rng.integers(1, 9))):
        r = float(np.exp(rng.uniform(np.log(12.0), np.log(90.0))))
        u, v = rng.uniform(-0.3 * r, width + 0.3 * r), rng.uniform(-0.3 * r, height + 0.3 * r)
        tag = int(rng.integers(0, 587)) if rng.random() < 0.8 else None
        nodes.append(SceneNode(u, v, r, tag=tag, tag_size=rng.uniform(0.5, 0.95), tag_angle=rng.uniform(-np.pi, np.pi),
                               tag_offset=tuple(rng.uniform(-0.35, 0.35, 2)), tag_tilt=rng.uniform(0.5, 1.0),
                               albedo=rng.uniform(120, 250)))
    return nodes


def mottled_frames(seed: int, frames: int = 10, *, width: int = 1024, height: int = 768) -> list[MottledFrame]:
    """``frames`` independent frames of mottled scene ``seed`` (each frame its own floor, discs and degradations)."""
    rng = np.random.default_rng([seed, 0x6D6F74])
    out = []
    for _ in range(frames):
        nodes = _discs(rng, width, height)
        bars = tuple(Bar((rng.uniform(0, width), rng.uniform(0, height)), (rng.uniform(0, width), rng.uniform(0, height)),
                         rng.uniform(4, 14), rng.uniform(30, 120)) for _ in range(int(rng.integers(0, 3))))
        config = SceneConfig(width=width, height=height, noise=rng.uniform(0, 6), blur=rng.uniform(0, 1.5),
                             exposure=rng.uniform(0.75, 1.25), bars=bars,
                             light=(rng.uniform(-0.6, 0.6), rng.uniform(-0.6, 0.6), -1.0))
        grey = draw_scene(nodes, config, rng, floor=mottled_floor(width, height, rng))
        tint = rng.uniform(0.8, 1.2, 3).astype(np.float32)  # a coloured floor and discs: one gain per channel
        image = np.clip(grey.astype(np.float32) * tint, 0, 255).astype(np.uint8)
        circles = np.array([[n.u, n.v, n.r] for n in nodes], float).reshape(-1, 3)
        out.append(MottledFrame(image, circles, visible_fraction(nodes, width, height)))
    return out
