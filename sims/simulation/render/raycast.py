"""Per-object ray casting into colour, depth and id buffers (vectorized numpy over each object's ROI).

Rays are unnormalized camera-frame directions ``d = K^{-1} [u, v, 1]^T`` (so ``d_z = 1``): a hit at
ray parameter ``t`` lies at camera depth ``z_c = t``, the value the depth buffer holds. Pixel (row i,
column j) is centred at image coordinates (u, v) = (j, i), OpenCV's convention.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from agents.perception.sphere_tags import StickerLayout  # the robot model: one layout for painter and reader

__all__ = ["Buffers", "StickerLayout", "DEFAULT_STICKERS", "pixel_rays", "draw_sphere", "draw_cylinder"]



DEFAULT_STICKERS = StickerLayout.around()

NEAR = 0.02


@dataclass
class Buffers:
    """Render targets: colour (H, W, 3) float32 BGR in [0, 1], depth (H, W) [m], ids (H, W) int32.

    ``ids`` holds the node id drawn at each pixel, -1 for floor/background and -2 for struts.
    """

    colour: np.ndarray
    depth: np.ndarray
    ids: np.ndarray


def pixel_rays(K: np.ndarray, width: int, height: int) -> np.ndarray:
    """Unnormalized rays (H, W, 3) float32 through every pixel centre, ``z = 1``."""
    Kinv = np.linalg.inv(K)
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    rays = np.stack([u, v, np.ones_like(u)], axis=-1) @ Kinv.T
    return rays.astype(np.float32)


def _roi(K, points_c, pad_px, width, height):
    """Pixel box (i0, i1, j0, j1) covering the projections of ``points_c`` (all in front), padded."""
    uv = (points_c @ K.T)[:, :2] / points_c[:, 2:3]
    j0 = max(int(np.floor(uv[:, 0].min() - pad_px)), 0)
    j1 = min(int(np.ceil(uv[:, 0].max() + pad_px)) + 1, width)
    i0 = max(int(np.floor(uv[:, 1].min() - pad_px)), 0)
    i1 = min(int(np.ceil(uv[:, 1].max() + pad_px)) + 1, height)
    return i0, i1, j0, j1


def _shade(normals, albedo, light, view):
    """Lambert plus a weak Phong highlight; ``normals``/``view`` (P, 3) unit, ``albedo`` (P, 3)."""
    ndl = np.clip(normals @ light, 0.0, None)
    refl = 2.0 * ndl[:, None] * normals - light[None, :]
    spec = np.clip(np.einsum("pk,pk->p", refl, view), 0.0, None) ** 24
    return albedo * (0.5 + 0.5 * ndl)[:, None] + 0.15 * spec[:, None]


def _sticker(n_node: np.ndarray, tag: np.ndarray, layout: StickerLayout):
    """Sticker reflectance at unit normals ``n_node`` (P, 3) in the node frame: (value (P,), inside (P,)).

    A surface point belongs to the sticker whose axis is nearest; its cell comes from the point's
    angular tangent coordinates about that axis, ``s1 = atan2(n . right, n . axis)`` and
    ``s2 = atan2(n . up, n . axis)``, each spanning 8 cells over ``2 half_angle``: the print bends
    with the sphere.
    """
    axes, up, right = (np.asarray(a, np.float32) for a in (layout.axes, layout.up, layout.right))
    dots = n_node @ axes.T
    best = np.argmax(dots, axis=1)
    along = dots[np.arange(len(n_node)), best]
    s1 = np.arctan2(np.einsum("pk,pk->p", n_node, right[best]), along)
    s2 = np.arctan2(np.einsum("pk,pk->p", n_node, up[best]), along)
    h = layout.half_angle
    inside = (np.abs(s1) < h) & (np.abs(s2) < h)
    col = np.clip(((s1 / h + 1) * 4).astype(int), 0, 7)
    row = np.clip(((1 - s2 / h) * 4).astype(int), 0, 7)
    value = np.where(tag[row, col], 0.95, 0.06).astype(np.float32)
    return value, inside


def draw_sphere(buf: Buffers, rays: np.ndarray, K: np.ndarray, centre, radius: float, R_node, node_id: int,
                light, *, tag: np.ndarray | None = None, body=(0.86, 0.86, 0.84),
                stickers: StickerLayout = DEFAULT_STICKERS) -> int:
    """Ray-cast a node sphere into ``buf`` with its tag stickers; return its silhouette pixel count.

    Parameters
    ----------
    centre : (3,)
        Sphere centre in the camera frame [m].
    radius : float
        r_0 [m].
    R_node : (3, 3)
        Orientation of the node frame (the assembly's root frame) in the camera frame.
    light : (3,)
        Unit direction towards the light, camera frame.
    tag : (8, 8) bool or None
        Sticker cells (True = white); ``None`` draws a plain sphere.
    stickers : StickerLayout
        Where copies of the tag sit on the sphere.
    """
    c = np.asarray(centre, dtype=np.float32)
    if c[2] - radius < NEAR:
        return 0
    H, W = buf.depth.shape
    corners = c[None, :] + radius * np.array(
        [[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float32
    )
    i0, i1, j0, j1 = _roi(K, corners, 2, W, H)
    if i0 >= i1 or j0 >= j1:
        return 0
    d = rays[i0:i1, j0:j1].reshape(-1, 3)
    a = np.einsum("pk,pk->p", d, d)
    b = d @ c
    disc = b * b - a * (float(c @ c) - radius * radius)
    hit = disc >= 0
    if not hit.any():
        return 0
    idx = np.flatnonzero(hit)
    t = (b[idx] - np.sqrt(disc[idx])) / a[idx]
    depth = buf.depth[i0:i1, j0:j1].reshape(-1)
    front = t < depth[idx]
    count = len(idx)
    idx, t = idx[front], t[front]
    if len(idx) == 0:
        return count
    dd = d[idx]
    point = dd * t[:, None]
    normal = (point - c) / radius
    albedo = np.broadcast_to(np.asarray(body, np.float32), (len(idx), 3)).copy()
    if tag is not None:
        # 4 sub-pixel rays per pixel (a 2 x 2 grid) average the sticker's cells: anti-aliased print
        Kinv = np.linalg.inv(K).astype(np.float32)
        level = np.zeros(len(idx), np.float32)
        inked = np.zeros(len(idx), bool)
        R_node = np.asarray(R_node, np.float32)
        for du, dv in ((-0.25, -0.25), (0.25, -0.25), (-0.25, 0.25), (0.25, 0.25)):
            ds = dd + Kinv[:, 0] * du + Kinv[:, 1] * dv
            a_s = np.einsum("pk,pk->p", ds, ds)
            b_s = ds @ c
            disc_s = np.maximum(b_s * b_s - a_s * (float(c @ c) - radius * radius), 0.0)
            t_s = (b_s - np.sqrt(disc_s)) / a_s
            n_s = (ds * t_s[:, None] - c) / radius
            value, inside = _sticker(n_s @ R_node, tag, stickers)  # rows: R_node^T n, the normal in the node frame
            level += np.where(inside, value, body[1]) * 0.25
            inked |= inside
        albedo[inked] = level[inked, None]
    view = -dd / np.linalg.norm(dd, axis=1, keepdims=True)
    shaded = _shade(normal, albedo, np.asarray(light, np.float32), view)
    colour = buf.colour[i0:i1, j0:j1].reshape(-1, 3)
    ids = buf.ids[i0:i1, j0:j1].reshape(-1)
    colour[idx] = shaded
    depth[idx] = t
    ids[idx] = node_id
    buf.colour[i0:i1, j0:j1] = colour.reshape(i1 - i0, j1 - j0, 3)
    buf.depth[i0:i1, j0:j1] = depth.reshape(i1 - i0, j1 - j0)
    buf.ids[i0:i1, j0:j1] = ids.reshape(i1 - i0, j1 - j0)
    return count


def draw_cylinder(buf: Buffers, rays: np.ndarray, K: np.ndarray, A, B, radius: float, light,
                  colour=(0.22, 0.2, 0.18)) -> None:
    """Ray-cast a strut: the cylinder of ``radius`` between points ``A`` and ``B`` (camera frame)."""
    A = np.asarray(A, np.float32)
    B = np.asarray(B, np.float32)
    # clip the segment to the part in front of the near plane
    za, zb = A[2] - radius, B[2] - radius
    if za < NEAR and zb < NEAR:
        return
    if za < NEAR or zb < NEAR:
        s = (NEAR + radius - A[2]) / (B[2] - A[2])
        cut = A + s * (B - A)
        A, B = (cut, B) if za < NEAR else (A, cut)
    axis = B - A
    length = float(np.linalg.norm(axis))
    if length < 1e-6:
        return
    ax = axis / length
    H, W = buf.depth.shape
    zmin = max(min(A[2], B[2]) - radius, NEAR)
    pad = K[0, 0] * radius / zmin + 2
    i0, i1, j0, j1 = _roi(K, np.stack([A, B]), pad, W, H)
    if i0 >= i1 or j0 >= j1:
        return
    d = rays[i0:i1, j0:j1].reshape(-1, 3)
    w = -A
    d_ax = d @ ax
    d_perp = d - d_ax[:, None] * ax
    w_perp = w - float(w @ ax) * ax
    a = np.einsum("pk,pk->p", d_perp, d_perp)
    b = 2.0 * (d_perp @ w_perp)
    cc = float(w_perp @ w_perp) - radius * radius
    disc = b * b - 4 * a * cc
    ok = (disc >= 0) & (a > 1e-12)
    idx = np.flatnonzero(ok)
    if len(idx) == 0:
        return
    t = (-b[idx] - np.sqrt(disc[idx])) / (2 * a[idx])
    point = d[idx] * t[:, None]
    s = (point - A) @ ax
    depth = buf.depth[i0:i1, j0:j1].reshape(-1)
    keep = (t > 0) & (s >= 0) & (s <= length) & (t < depth[idx])
    idx, t, point, s = idx[keep], t[keep], point[keep], s[keep]
    if len(idx) == 0:
        return
    normal = point - (A + s[:, None] * ax)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    albedo = np.broadcast_to(np.asarray(colour, np.float32), (len(idx), 3))
    view = -d[idx] / np.linalg.norm(d[idx], axis=1, keepdims=True)
    shaded = _shade(normal, albedo, np.asarray(light, np.float32), view)
    col = buf.colour[i0:i1, j0:j1].reshape(-1, 3)
    ids = buf.ids[i0:i1, j0:j1].reshape(-1)
    col[idx] = shaded
    depth[idx] = t
    ids[idx] = -2
    buf.colour[i0:i1, j0:j1] = col.reshape(i1 - i0, j1 - j0, 3)
    buf.depth[i0:i1, j0:j1] = depth.reshape(i1 - i0, j1 - j0)
    buf.ids[i0:i1, j0:j1] = ids.reshape(i1 - i0, j1 - j0)
