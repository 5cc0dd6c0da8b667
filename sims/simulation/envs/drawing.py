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
    _scale_bar(img, scale)
    _legend(img, with_links=bool(link_loss), with_nodes=bool(nodes),
            with_ellipses=any(len(it) > 2 for v in (estimates or {}).values() for it in v))
    return img


def _nice_length(target: float) -> float:
    """The largest of 1, 2, 5 x 10^k not above ``target`` (metres)."""
    base = 10.0 ** np.floor(np.log10(target))
    return float(max(m * base for m in (1, 2, 5) if m * base <= target))


def _scale_bar(img: np.ndarray, scale: float) -> None:
    """A scale bar of a round length (about a fifth of the view) in the bottom-right corner."""
    size = img.shape[1]
    metres = _nice_length(0.2 * size / scale)
    length = int(round(metres * scale))
    x1, y = size - 16, img.shape[0] - 18
    x0 = x1 - length
    cv2.rectangle(img, (x0 - 6, y - 18), (x1 + 6, y + 8), (255, 255, 255), -1)
    cv2.line(img, (x0, y), (x1, y), (0, 0, 0), 2)
    for x in (x0, x1):
        cv2.line(img, (x, y - 4), (x, y + 4), (0, 0, 0), 1)
    label = f"{metres:g} m"
    (tw, _), _ = cv2.getTextSize(label, cv2.FONT_HERSHEY_SIMPLEX, 0.4, 1)
    cv2.putText(img, label, ((x0 + x1 - tw) // 2, y - 7), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1, cv2.LINE_AA)


def _legend(img: np.ndarray, *, with_links: bool, with_ellipses: bool, with_nodes: bool) -> None:
    """What the marks mean, in a box in the top-left corner."""
    grey, dark = (90, 90, 90), (0, 0, 0)
    rows = [("disc", "robot, true pose (tick: heading)"), ("cross", "estimate (line to its truth = error)")]
    if with_nodes:
        rows.append(("node", "node of an assembly"))
    if with_ellipses:
        rows.append(("ellipse", "2-sigma position ellipse"))
    if with_links:
        rows.append(("link", "radio link: green no loss .. red all lost"))
    rows.append(("fan", "camera field of view"))
    font, fs = cv2.FONT_HERSHEY_SIMPLEX, 0.36
    width = 34 + max(cv2.getTextSize(text, font, fs, 1)[0][0] for _, text in rows)
    x0, y0, h = 4, 4, 15
    overlay = img.copy()
    cv2.rectangle(overlay, (x0, y0), (x0 + width, y0 + 6 + h * len(rows)), (255, 255, 255), -1)
    img[:] = cv2.addWeighted(overlay, 0.85, img, 0.15, 0)
    cv2.rectangle(img, (x0, y0), (x0 + width, y0 + 6 + h * len(rows)), (160, 160, 160), 1)
    for n, (kind, text) in enumerate(rows):
        cx, cy = x0 + 14, y0 + 11 + h * n
        if kind == "disc":
            cv2.circle(img, (cx, cy), 4, grey, -1, cv2.LINE_AA)
            cv2.line(img, (cx, cy), (cx + 8, cy), dark, 1, cv2.LINE_AA)
        elif kind == "cross":
            cv2.drawMarker(img, (cx, cy), grey, cv2.MARKER_CROSS, 7, 1, cv2.LINE_AA)
            cv2.line(img, (cx, cy), (cx + 9, cy + 3), grey, 1, cv2.LINE_AA)
        elif kind == "node":
            cv2.circle(img, (cx, cy), 4, grey, 1, cv2.LINE_AA)
        elif kind == "ellipse":
            cv2.ellipse(img, (cx, cy), (8, 4), 20, 0, 360, grey, 1, cv2.LINE_AA)
        elif kind == "link":
            cv2.line(img, (cx - 9, cy), (cx, cy), (0, 200, 0), 2, cv2.LINE_AA)
            cv2.line(img, (cx, cy), (cx + 9, cy), (255, 0, 0), 2, cv2.LINE_AA)
        else:
            cv2.fillPoly(img, [np.array([(cx - 9, cy + 5), (cx + 9, cy - 5), (cx + 9, cy + 5)], np.int32)],
                         (225, 225, 235))
        cv2.putText(img, text, (x0 + 28, cy + 4), font, fs, dark, 1, cv2.LINE_AA)


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


def compose_frame(top: np.ndarray, cameras: list[np.ndarray], columns: int | None = None) -> np.ndarray:
    """Top view on the left, camera views in a grid on the right, scaled to the top view's height.

    ``columns`` defaults to the most columns whose grid is no wider than the top view; the tiles keep
    the cameras' aspect ratio and together fill the canvas's height, so nothing is left blank but the
    spare cells of the last row.
    """
    if not cameras:
        return top
    n = len(cameras)
    ch, cw = cameras[0].shape[:2]

    def tile(cols: int) -> tuple[int, int]:
        h = top.shape[0] // -(-n // cols)
        return h, max(int(round(h * cw / ch)), 1)

    if columns is None:
        columns = max([c for c in range(1, n + 1) if c * tile(c)[1] <= top.shape[1]], default=1)
    th, tw = tile(columns)
    grid = np.full((top.shape[0], columns * tw, 3), 40, np.uint8)
    for k, cam in enumerate(cameras):
        r, c = divmod(k, columns)
        grid[r * th:(r + 1) * th, c * tw:(c + 1) * tw] = cv2.resize(cam, (tw, th), interpolation=cv2.INTER_LINEAR)
    return np.concatenate([top, grid], axis=1)
