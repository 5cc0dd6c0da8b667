"""OpenCV drawings of a swarm step: a top view (truth, estimates, radio links) and camera views.

Only :mod:`sims` imports OpenCV. Images are ``uint8`` RGB arrays of shape (H, W, 3).
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["top_view", "camera_view", "compose_frame"]

_PALETTE = [
    (230, 25, 75), (60, 180, 75), (0, 130, 200), (245, 130, 48), (145, 30, 180), (70, 240, 240),
    (240, 50, 230), (210, 245, 60), (250, 190, 212), (0, 128, 128), (170, 110, 40), (128, 0, 0),
]


def colour(i: int) -> tuple[int, int, int]:
    """A distinct RGB colour for robot index ``i``."""
    return _PALETTE[i % len(_PALETTE)]


def top_view(
    states: np.ndarray,
    arena: float,
    *,
    estimates: dict[int, list[tuple[int, np.ndarray]]] | None = None,
    link_loss: dict[tuple[int, int], float] | None = None,
    max_angle: float = 0.8,
    max_distance: float = 3.0,
    node_radius: float = 0.06,
    size: int = 480,
    nodes: list[tuple[int, np.ndarray]] | None = None,
    fans: list[tuple[int, np.ndarray, float]] | None = None,
) -> np.ndarray:
    """Top view of the arena.

    Parameters
    ----------
    states : ndarray, shape (n, 3)
        True ``(x, y, theta)`` of each robot in W.
    arena : float
        Side of the square arena [m].
    estimates : dict, optional
        Observer index -> list of (target index, estimated target pose (3,) in W[, position
        covariance (2, 2) in W]); drawn as crosses in the observer's colour joined to the target's
        true position (the error), with a 2-sigma ellipse when the covariance is given.
    link_loss : dict, optional
        ``(i, j)`` -> recent loss fraction in [0, 1]; drawn as lines from green (0) to red (1).
    max_angle, max_distance : float
        View cone of each camera [rad], [m].
    nodes : list, optional
        (robot index, node centres (N, 2) in W): every node of a multi-node assembly.
    fans : list, optional
        (robot index, camera position (2,) in W, camera yaw in W) of each view cone; default one cone
        per robot along its heading.
    """
    img = np.full((size, size, 3), 250, np.uint8)
    scale = (size - 20) / arena

    def px(xy) -> tuple[int, int]:
        return int(round(10 + xy[0] * scale)), int(round(size - 10 - xy[1] * scale))

    cv2.rectangle(img, px((0, 0)), px((arena, arena)), (180, 180, 180), 1)
    for (i, j), loss in sorted((link_loss or {}).items()):
        c = (int(255 * loss), int(200 * (1 - loss)), 0)
        cv2.line(img, px(states[i, :2]), px(states[j, :2]), c, 1, cv2.LINE_AA)
    for i, xy in nodes or ():
        r = max(int(node_radius * scale), 2)
        for c in xy:
            cv2.circle(img, px(c), r, colour(i), 1, cv2.LINE_AA)
    if fans is None:
        fans = [(i, states[i, :2], float(states[i, 2])) for i in range(len(states))]
    for i, (cx, cy), th in fans:
        fan = [px((cx, cy))]
        for a in np.linspace(th - max_angle, th + max_angle, 9):
            fan.append(px((cx + max_distance * np.cos(a), cy + max_distance * np.sin(a))))
        overlay = img.copy()
        cv2.fillPoly(overlay, [np.array(fan, np.int32)], colour(i))
        img = cv2.addWeighted(overlay, 0.08, img, 0.92, 0)
    for i, (x, y, th) in enumerate(states):
        col = colour(i)
        r = max(int(node_radius * scale), 3)
        cv2.circle(img, px((x, y)), r, col, -1, cv2.LINE_AA)
        cv2.line(img, px((x, y)), px((x + 2.5 * node_radius * np.cos(th), y + 2.5 * node_radius * np.sin(th))),
                 (0, 0, 0), 1, cv2.LINE_AA)
        cv2.putText(img, str(i), px((x + node_radius, y + node_radius)), cv2.FONT_HERSHEY_SIMPLEX, 0.35,
                    (0, 0, 0), 1, cv2.LINE_AA)
    for i, items in sorted((estimates or {}).items()):
        col = colour(i)
        for item in items:
            j, pose = item[0], item[1]
            p = px(pose[:2])
            cv2.line(img, p, px(states[j, :2]), col, 1, cv2.LINE_AA)
            cv2.drawMarker(img, p, col, cv2.MARKER_CROSS, 7, 1, cv2.LINE_AA)
            if len(item) > 2:  # 2-sigma position ellipse, covariance (2, 2) in W
                vals, vecs = np.linalg.eigh(item[2])
                axes = tuple(int(min(2 * np.sqrt(max(v, 0.0)) * scale, 4 * size)) for v in vals[::-1])
                angle = -np.degrees(np.arctan2(vecs[1, 1], vecs[0, 1]))
                cv2.ellipse(img, p, axes, angle, 0, 360, col, 1, cv2.LINE_AA)
    return img


def camera_view(
    detections: list[tuple[int, float, float, float]],
    width: int,
    height: int,
    *,
    label: str = "",
    size: tuple[int, int] = (160, 120),
) -> np.ndarray:
    """A camera's image reduced to ``size``: each detection (id, u, v, r) as a labelled circle."""
    w, h = size
    img = np.full((h, w, 3), 40, np.uint8)
    sx, sy = w / width, h / height
    for node, u, v, r in detections:
        c = colour(node)
        cv2.circle(img, (int(u * sx), int(v * sy)), max(int(r * sx), 1), c, -1, cv2.LINE_AA)
        cv2.putText(img, str(node), (int(u * sx) + 2, int(v * sy) - 2), cv2.FONT_HERSHEY_SIMPLEX, 0.3,
                    (255, 255, 255), 1, cv2.LINE_AA)
    cv2.putText(img, label, (3, 11), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (255, 255, 255), 1, cv2.LINE_AA)
    cv2.rectangle(img, (0, 0), (w - 1, h - 1), (120, 120, 120), 1)
    return img


def compose_frame(top: np.ndarray, cameras: list[np.ndarray], columns: int = 3) -> np.ndarray:
    """Top view on the left, camera views in a grid of ``columns`` on the right."""
    if not cameras:
        return top
    ch, cw = cameras[0].shape[:2]
    rows = -(-len(cameras) // columns)
    grid = np.full((max(rows * ch, top.shape[0]), columns * cw, 3), 255, np.uint8)
    for n, cam in enumerate(cameras):
        r, c = divmod(n, columns)
        grid[r * ch:(r + 1) * ch, c * cw:(c + 1) * cw] = cam
    height = max(top.shape[0], grid.shape[0])
    out = np.full((height, top.shape[1] + grid.shape[1], 3), 255, np.uint8)
    out[: top.shape[0], : top.shape[1]] = top
    out[: grid.shape[0], top.shape[1]:] = grid
    return out
