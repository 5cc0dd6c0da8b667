"""A small 2-D image synthesizer for perception tests and benchmarks (no 3-D geometry).

It draws what the perception front end has to cope with, directly in the image plane: shaded discs
(spherical nodes) with an AprilTag 36h11 sticker warped onto each, drawn far-to-near so nearer discs
occlude farther ones, optional bars over them (struts), a textured floor, sensor noise and blur. The
true circle of every disc is known exactly, so detector accuracy can be scored to sub-pixel level.
The full 3-D renderer lives in :mod:`sims.simulation.render`; this one exists so perception can be tested on
controlled cases (a tag drop-out of exactly five frames, two nodes crossing) that are awkward to
stage in 3-D.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

__all__ = ["SceneNode", "Bar", "SceneConfig", "disc_patch", "draw_scene", "floor_texture", "visible_fraction"]

_DICT = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)


@dataclass(frozen=True)
class SceneNode:
    """One disc in the image: centre ``(u, v)`` and radius ``r`` in pixels.

    ``tag`` is the AprilTag 36h11 id on it (None: no tag visible), ``tag_size`` the tag's side as a
    fraction of ``r``, ``tag_angle`` its in-plane rotation (rad), ``tag_offset`` its centre offset from
    the disc centre as a fraction of ``r`` (u, v), ``tag_tilt`` a foreshortening factor in (0, 1] along
    the offset direction (a tag seen obliquely on the sphere), ``albedo`` the disc brightness (0-255).
    """

    u: float
    v: float
    r: float
    tag: int | None = None
    tag_size: float = 0.9
    tag_angle: float = 0.0
    tag_offset: tuple[float, float] = (0.0, 0.0)
    tag_tilt: float = 1.0
    albedo: float = 235.0


@dataclass(frozen=True)
class Bar:
    """A straight occluding bar (a strut seen from the side) from ``p0`` to ``p1`` (pixels)."""

    p0: tuple[float, float]
    p1: tuple[float, float]
    width: float = 10.0
    intensity: float = 60.0


@dataclass(frozen=True)
class SceneConfig:
    """Image size and degradations: Gaussian sensor noise ``noise`` (grey levels), blur ``blur``
    (Gaussian sigma in px), horizontal motion blur length ``motion_blur`` (px), ``exposure`` gain."""

    width: int = 1024
    height: int = 768
    noise: float = 0.0
    blur: float = 0.0
    motion_blur: int = 0
    exposure: float = 1.0
    light: tuple[float, float, float] = (-0.4, -0.5, -0.77)
    bars: tuple[Bar, ...] = field(default_factory=tuple)


def floor_texture(width: int, height: int, rng: np.random.Generator) -> np.ndarray:
    """Return a smooth random floor texture, shape (height, width), float32 grey levels about 70-130."""
    small = rng.uniform(0.0, 1.0, size=(height // 16 + 2, width // 16 + 2)).astype(np.float32)
    tex = cv2.resize(small, (width, height), interpolation=cv2.INTER_CUBIC)
    fine = cv2.GaussianBlur(rng.uniform(0, 1, size=(height, width)).astype(np.float32), (0, 0), 1.5)
    return 75.0 + 45.0 * np.clip(tex, 0, 1) + 16.0 * (fine - 0.5)


def _tag_bits(tag: int, cells_px: int) -> np.ndarray:
    # 36h11 marker (8 x 8 cells with its black border) inside one white cell of quiet zone
    inner = cv2.aruco.generateImageMarker(_DICT, int(tag), 8 * cells_px, borderBits=1)
    return cv2.copyMakeBorder(inner, cells_px, cells_px, cells_px, cells_px, cv2.BORDER_CONSTANT, value=255)


def disc_patch(u: float, v: float, r: float, pad: int, width: int, height: int):
    """The pixels around a disc of centre (u, v) and radius r (px), padded by ``pad``, clipped to the image.

    Returns None when nothing of it is in the image, else ``(x0, y0, dx, dy, alpha, nz)``: the
    patch's top-left pixel, the offsets from the centre in radii, the disc's anti-aliased coverage
    and the z of a unit sphere's normal, each (h, w) float32 (pixel centres at integer coordinates,
    OpenCV's convention).
    """
    x0, x1 = max(int(np.floor(u - r)) - pad, 0), min(int(np.ceil(u + r)) + pad + 1, width)
    y0, y1 = max(int(np.floor(v - r)) - pad, 0), min(int(np.ceil(v + r)) + pad + 1, height)
    if x0 >= x1 or y0 >= y1:
        return None
    ys, xs = np.mgrid[y0:y1, x0:x1].astype(np.float32)
    dx, dy = (xs - u) / r, (ys - v) / r
    alpha = np.clip(r - np.hypot(xs - u, ys - v) + 0.5, 0.0, 1.0)
    nz = np.sqrt(np.clip(1.0 - dx * dx - dy * dy, 0.0, 1.0))
    return x0, y0, dx, dy, alpha, nz


def _draw_disc(img: np.ndarray, node: SceneNode, light: np.ndarray) -> None:
    h, w = img.shape
    patch = disc_patch(node.u, node.v, node.r, 2, w, h)
    if patch is None:
        return
    x0, y0, dx, dy, alpha, nz = patch
    x1, y1 = x0 + dx.shape[1], y0 + dx.shape[0]
    lambert = np.clip(dx * light[0] + dy * light[1] - nz * light[2], 0.0, 1.0)
    shade = node.albedo * (0.35 + 0.65 * lambert)
    if node.tag is not None:
        cells = 10  # 8 marker cells + quiet zone of one cell each side
        cpx = max(int(np.ceil(node.r * node.tag_size / 8)), 2)
        tex = _tag_bits(node.tag, cpx).astype(np.float32) / 255.0
        side = node.r * node.tag_size * cells / 8.0
        c, s = np.cos(node.tag_angle), np.sin(node.tag_angle)
        half = side / 2.0
        corners = np.array([[-half, -half], [half, -half], [half, half], [-half, half]])
        corners = corners @ np.array([[c, s], [-s, c]])
        off = np.array(node.tag_offset, dtype=float)
        if node.tag_tilt < 1.0 and np.linalg.norm(off) > 0:
            n = off / np.linalg.norm(off)
            along = corners @ n
            corners = corners - np.outer(along * (1.0 - node.tag_tilt), n)
        corners = corners + off * node.r + np.array([node.u - x0, node.v - y0])
        src = np.array([[0, 0], [tex.shape[1], 0], [tex.shape[1], tex.shape[0]], [0, tex.shape[0]]], np.float32)
        src -= 0.5
        H = cv2.getPerspectiveTransform(src, corners.astype(np.float32))
        warped = cv2.warpPerspective(tex, H, (x1 - x0, y1 - y0), flags=cv2.INTER_AREA, borderValue=1.0)
        shade = shade * (0.12 + 0.88 * warped)
    patch = img[y0:y1, x0:x1]
    patch[:] = alpha * shade + (1.0 - alpha) * patch


def draw_scene(
    nodes: list[SceneNode] | tuple[SceneNode, ...],
    config: SceneConfig,
    rng: np.random.Generator,
    *,
    floor: np.ndarray | None = None,
) -> np.ndarray:
    """Draw one frame; return a (height, width, 3) uint8 BGR image.

    Discs are drawn in increasing radius (far to near), then the bars, then blur, exposure and
    noise. ``rng`` draws the sensor noise (and the floor, when ``floor`` is not given).
    """
    img = (floor if floor is not None else floor_texture(config.width, config.height, rng)).astype(np.float32)
    img = img.copy()
    light = np.asarray(config.light, dtype=float)
    light = light / np.linalg.norm(light)
    for node in sorted(nodes, key=lambda n: n.r):
        _draw_disc(img, node, light)
    for bar in config.bars:
        cv2.line(img, tuple(int(round(x)) for x in bar.p0), tuple(int(round(x)) for x in bar.p1),
                 float(bar.intensity), int(round(bar.width)), lineType=cv2.LINE_AA)
    if config.blur > 0:
        img = cv2.GaussianBlur(img, (0, 0), config.blur)
    if config.motion_blur > 1:
        kernel = np.full((1, config.motion_blur), 1.0 / config.motion_blur, np.float32)
        img = cv2.filter2D(img, -1, kernel)
    img = img * config.exposure
    if config.noise > 0:
        img = img + rng.normal(0.0, config.noise, size=img.shape).astype(np.float32)
    grey = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    return cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR)


def visible_fraction(nodes: list[SceneNode] | tuple[SceneNode, ...], width: int, height: int) -> np.ndarray:
    """Fraction of each disc's area that is inside the image and not covered by a larger disc, shape (N,).

    Bars are not counted (they are thin); larger discs are nearer and drawn over smaller ones.
    """
    out = np.zeros(len(nodes))
    for i, n in enumerate(nodes):
        x0, x1 = int(np.floor(n.u - n.r)), int(np.ceil(n.u + n.r)) + 1
        y0, y1 = int(np.floor(n.v - n.r)), int(np.ceil(n.v + n.r)) + 1
        ys, xs = np.mgrid[y0:y1, x0:x1]
        disc = np.hypot(xs - n.u, ys - n.v) <= n.r
        total = disc.sum()
        vis = disc & (xs >= 0) & (xs < width) & (ys >= 0) & (ys < height)
        for m in nodes:
            if m is not n and m.r > n.r:
                vis &= np.hypot(xs - m.u, ys - m.v) > m.r
        out[i] = vis.sum() / max(total, 1)
    return out
