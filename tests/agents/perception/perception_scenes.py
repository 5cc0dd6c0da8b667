"""Synthetic frames for the perception tests (image-plane discs with tags, see sims.lab.experiments.synthetic_scene)."""

import numpy as np

from sims.lab.experiments.synthetic_scene import SceneConfig, SceneNode, draw_scene, floor_texture

W, H = 640, 480


def frame(nodes, *, noise=0.0, blur=0.0, seed=0, floor=None, bars=()):
    """One BGR frame of ``nodes`` (SceneNode list) on a fixed textured floor."""
    rng = np.random.default_rng(seed)
    if floor is None:
        floor = floor_texture(W, H, np.random.default_rng(1000))
    return draw_scene(nodes, SceneConfig(width=W, height=H, noise=noise, blur=blur, bars=tuple(bars)), rng, floor=floor)


def layout(seed=0, count=5):
    """``count`` non-overlapping discs of radius 22-45 px with distinct tags, well inside the image."""
    rng = np.random.default_rng(seed)
    nodes = []
    while len(nodes) < count:
        r = rng.uniform(22, 45)
        u, v = rng.uniform(r + 10, W - r - 10), rng.uniform(r + 10, H - r - 10)
        if all(np.hypot(u - n.u, v - n.v) > r + n.r + 12 for n in nodes):
            nodes.append(SceneNode(u, v, r, tag=int(rng.integers(0, 587)), tag_angle=rng.uniform(-0.4, 0.4), tag_size=0.75))
    return nodes
