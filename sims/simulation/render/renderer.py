"""Rendering a simulated world's camera frames: shaded tagged spheres, struts, a textured floor.

For a camera at a step the renderer draws, in any order thanks to a depth buffer: the floor plane
``z = 0`` of W (a texture warped by the floor-to-image homography), every node of every assembly as
a shaded sphere carrying AprilTag 36h11 stickers (tag id = node id, four around the equator and one
on top, mapped onto the surface through each surface point's angular tangent coordinates so they
bend with the sphere), and every strut as an occluding cylinder. The observer's own body is drawn
too. Camera effects (exposure, motion blur, optical blur, noise, JPEG) come last.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import cv2
import numpy as np

from sims.simulation.render.effects import apply_effects
from sims.simulation.render.raycast import Buffers, StickerLayout, draw_cylinder, draw_sphere, pixel_rays
from sims.simulation.render.textures import floor_texture, tag_cells
from sims.simulation.world.camera import silhouette_circle
from sims.simulation.world.world import CameraRig, World

__all__ = ["RenderConfig", "Frame", "Renderer"]


@dataclass(frozen=True)
class RenderConfig:
    """Rendering knobs (defaults: an ESP32-CAM-like camera at 5 Hz).

    Attributes
    ----------
    strut_radius : float
        Radius [m] of the strut cylinders.
    noise_sigma : float
        Sensor noise std [8-bit grey levels].
    blur_sigma : float
        Optical blur std [px].
    shutter : float
        Exposure time as a fraction of the frame interval: the motion blur is this fraction of the
        scene's image motion between consecutive frames.
    exposure_sigma : float
        Std of the log exposure gain; the gain drifts from frame to frame (AR(1), correlation 0.8).
    jpeg_quality : int
        JPEG re-encoding quality (0: off).
    light : tuple
        Direction towards the light in W.
    floor_seed_metres : float
        Side [m] of the floor texture tile (it repeats beyond).
    tags_around : int
        Copies of a node's AprilTag around its equator (one more sits on top).
    tag_half_angle : float
        Half the angular size [rad] of a sticker seen from the sphere's centre (must be
        < pi / tags_around); 0.33 rad makes a 4 cm tag on a 12 cm sphere.
    wall_levels : tuple of 2 floats
        Brightness (0-1) of the plain wall above the horizon at the image's top and bottom rows.
    wall_tint : tuple of 3 floats
        The wall's colour, as factors (0-1) of its brightness in B, G, R.
    """

    strut_radius: float = 0.018
    noise_sigma: float = 3.0
    blur_sigma: float = 0.7
    shutter: float = 0.15
    exposure_sigma: float = 0.12
    jpeg_quality: int = 0
    light: tuple = (0.35, 0.25, 1.0)
    floor_seed_metres: float = 16.0
    tags_around: int = 8
    tag_half_angle: float = 0.33
    wall_levels: tuple = (0.85, 0.7)
    wall_tint: tuple = (0.95, 0.93, 0.9)

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, (int, float)) and not (np.isfinite(v) and v >= 0):
                raise ValueError(f"{f.name} must be a finite non-negative number, got {v!r}")
        if self.jpeg_quality > 100:
            raise ValueError("jpeg_quality must be in 0..100")
        for name, size in (("wall_levels", 2), ("wall_tint", 3)):
            v = np.asarray(getattr(self, name), dtype=float)
            if v.shape != (size,) or not np.all((v >= 0) & (v <= 1)):
                raise ValueError(f"{name} must be {size} numbers in [0, 1], got {getattr(self, name)!r}")
        StickerLayout.around(self.tags_around, self.tag_half_angle)  # raises if the stickers overlap

    @classmethod
    def clean(cls, **changes) -> "RenderConfig":
        """No sensor noise, blur, motion blur or exposure changes: the geometry as rendered."""
        return cls(**{"noise_sigma": 0.0, "blur_sigma": 0.0, "shutter": 0.0, "exposure_sigma": 0.0, **changes})


@dataclass(frozen=True)
class Frame:
    """One rendered frame and what it shows.

    Attributes
    ----------
    image : ndarray, shape (H, W, 3) uint8
        BGR frame.
    nodes : list[dict]
        The nodes with at least one visible pixel: ``id``; the model circle ``u``, ``v``, ``r``
        (Liu et al. 2024 eq. (1) inverted: projected centre, ``f r_0 / z_c``); the exact silhouette's
        centre and equal-area radius ``su``, ``sv``, ``sr``; and ``visible``, the fraction of the
        silhouette's pixels not hidden by nearer objects.
    """

    image: np.ndarray
    nodes: list


class Renderer:
    """Renders the frames of one world's cameras.

    Parameters
    ----------
    world : World
    config : RenderConfig
    rng : np.random.Generator
        Draws the floor texture; per-camera effect streams are passed to :meth:`render`.
    """

    def __init__(self, world: World, config: RenderConfig, rng: np.random.Generator):
        self.world = world
        self.config = config
        self.texture = (floor_texture(rng, metres=config.floor_seed_metres) * 255).astype(np.uint8)
        self._pool_rng = rng
        self._noise_pool: np.ndarray | None = None
        self._rays: dict[str, np.ndarray] = {}
        self._gain: dict[str, float] = {}
        light = np.asarray(config.light, dtype=float)
        self.light_world = light / np.linalg.norm(light)
        self.stickers = StickerLayout.around(config.tags_around, config.tag_half_angle)

    def noise_pool(self, image_size: int) -> np.ndarray:
        """Standard normal samples shared by all frames (drawn once, twice the largest image)."""
        if self._noise_pool is None or self._noise_pool.size < image_size + 1:
            self._noise_pool = self._pool_rng.standard_normal(2 * image_size + 4096, dtype=np.float32)
        return self._noise_pool

    def rays(self, rig: CameraRig) -> np.ndarray:
        """Cached pixel rays of ``rig``'s camera."""
        if rig.key not in self._rays:
            self._rays[rig.key] = pixel_rays(rig.spec.K, rig.spec.width, rig.spec.height)
        return self._rays[rig.key]

    def _floor(self, rig: CameraRig, cam) -> Buffers:
        spec = rig.spec
        W, H = spec.width, spec.height
        K = spec.K
        R, o = cam.R, cam.p
        # world z of each pixel's ray direction is linear in (u, v): row 2 of R K^-1
        a = (R @ np.linalg.inv(K))[2].astype(np.float32)
        u = np.arange(W, dtype=np.float32)
        v = np.arange(H, dtype=np.float32)
        dz = a[0] * u[None, :] + (a[1] * v + a[2])[:, None]
        with np.errstate(divide="ignore"):
            depth = np.float32(-o[2]) / dz  # ray parameter = camera depth, since d_z = 1 in c
        depth[~(dz < -1e-6) | (o[2] <= 0)] = np.inf
        # floor texture pixel (j, i) is the W point (x0 + j s, y0 + i s, 0); its image is K R^T (X - o)
        side = self.texture.shape[0]
        s = self.config.floor_seed_metres / side
        x0 = y0 = -self.config.floor_seed_metres / 2
        A = np.array([[s, 0, x0 - o[0]], [0, s, y0 - o[1]], [0, 0, -o[2]]])
        floor = cv2.warpPerspective(self.texture, K @ R.T @ A, (W, H), flags=cv2.INTER_LINEAR,
                                    borderMode=cv2.BORDER_WRAP)
        colour = floor.astype(np.float32) * np.float32(0.9 / 255.0)
        # above the horizon: a plain wall, lighter towards the top; the horizon row varies with u, so
        # fill whole rows that lie entirely above it and mask only the rows it crosses
        sky_rows = np.linspace(*self.config.wall_levels, H, dtype=np.float32)
        up = ~np.isfinite(depth)
        rows = np.flatnonzero(up.any(axis=1))
        if len(rows):
            tint = np.array(self.config.wall_tint, np.float32)
            block = colour[rows]
            block[up[rows]] = (sky_rows[rows][:, None] * np.ones(W, np.float32))[up[rows]][:, None] * tint
            colour[rows] = block
        return Buffers(colour, depth, np.full((H, W), -1, np.int32))

    def render_linear(self, rig: CameraRig, k: int) -> tuple[Buffers, dict, dict]:
        """Draw the scene for ``rig`` at step ``k`` without camera effects.

        Returns the buffers, each node's silhouette pixel count, and each node's true circle.
        """
        world = self.world
        cam = world.camera_in_world(rig, k)
        K = rig.spec.K
        rays = self.rays(rig)
        buf = self._floor(rig, cam)
        light = (cam.R.T @ self.light_world).astype(np.float32)
        silhouettes, circles = {}, {}
        for track in world.assemblies:
            root = track.root_pose(k, world.node_radius)
            shape = track.shapes[k]
            centres_w = root.apply(shape.centres)
            centres_c = (centres_w - cam.p) @ cam.R
            R_node = cam.R.T @ root.R
            where = {}
            for node, c in zip(shape.ids, centres_c):
                where[node] = c
                silhouettes[node] = draw_sphere(buf, rays, K, c, world.node_radius, R_node, node, light,
                                                tag=tag_cells(node), stickers=self.stickers)
                if c[2] > world.node_radius:
                    uvw = K @ c
                    # Liu et al. 2024 eq. (1) inverted, and the sphere's exact silhouette (an ellipse)
                    circles[node] = (uvw[0] / c[2], uvw[1] / c[2], K[0, 0] * world.node_radius / c[2],
                                     *silhouette_circle(K, c, world.node_radius))
            for a, b in shape.struts:
                draw_cylinder(buf, rays, K, where[a], where[b], self.config.strut_radius, light)
        return buf, silhouettes, circles

    def _motion(self, rig: CameraRig, k: int) -> tuple[float, float]:
        """Mean image motion [px] of the nodes in view between steps k-1 and k, times the shutter."""
        if k == 0 or self.config.shutter == 0:
            return (0.0, 0.0)
        world, K = self.world, rig.spec.K
        seen = []
        for kk in (k - 1, k):
            cam = world.camera_in_world(rig, kk)
            ids, _, centres = world.nodes_in_world(kk)
            seen.append(dict(zip(ids.tolist(), (centres - cam.p) @ cam.R)))
        common = sorted(set(seen[0]) & set(seen[1]))
        if not common:
            return (0.0, 0.0)
        a = np.array([seen[0][i] for i in common])
        b = np.array([seen[1][i] for i in common])
        ok = (a[:, 2] > 0.2) & (b[:, 2] > 0.2)
        if not ok.any():
            return (0.0, 0.0)
        ua = (a[ok] @ K.T)[:, :2] / a[ok, 2:3]
        ub = (b[ok] @ K.T)[:, :2] / b[ok, 2:3]
        inside = (ub[:, 0] > 0) & (ub[:, 0] < rig.spec.width) & (ub[:, 1] > 0) & (ub[:, 1] < rig.spec.height)
        if not inside.any():
            inside = np.ones(len(ub), bool)
        dx, dy = (ub[inside] - ua[inside]).mean(axis=0) * self.config.shutter
        return (float(dx), float(dy))

    def render(self, rig: CameraRig, k: int, rng: np.random.Generator) -> Frame:
        """The 8-bit frame of ``rig`` at step ``k`` with camera effects drawn from ``rng``."""
        buf, silhouettes, circles = self.render_linear(rig, k)
        c = self.config
        z = float(rng.standard_normal())
        prev = self._gain.get(rig.key, 0.0)
        log_gain = 0.8 * prev + np.sqrt(1 - 0.8**2) * c.exposure_sigma * z if k else c.exposure_sigma * z
        self._gain[rig.key] = log_gain
        image = apply_effects(buf.colour, rng, gain=float(np.exp(log_gain)), motion=self._motion(rig, k),
                              blur_sigma=c.blur_sigma, noise_sigma=c.noise_sigma, jpeg_quality=c.jpeg_quality,
                              noise_pool=self.noise_pool(image_size=buf.colour.size) if c.noise_sigma else None)
        counts = np.bincount(buf.ids[buf.ids >= 0].ravel()) if (buf.ids >= 0).any() else np.zeros(0, int)
        nodes = []
        for node, total in silhouettes.items():
            seen = int(counts[node]) if node < len(counts) else 0
            if seen and total and node in circles:
                u, v, r, su, sv, sr = circles[node]
                nodes.append({"id": int(node), "u": float(u), "v": float(v), "r": float(r),
                              "su": float(su), "sv": float(sv), "sr": float(sr),
                              "visible": round(seen / total, 4)})
        return Frame(image, nodes)
