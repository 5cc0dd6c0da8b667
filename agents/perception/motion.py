"""Camera-motion compensation: the image motion between frames caused by the observer moving.

BoT-SORT compensates the camera's own motion before associating [1]_. Two sources are offered:

- :func:`odometry_homography`: from the observer's own odometry (its root's yaw change) and the
  camera's mounting, the homography of the camera's rotation ``K R^T K^-1`` (translation is
  ignored: its image motion depends on depth; at the paper's speeds and 5 Hz it is the rotation
  that moves the image most);
- :class:`FlowRegistration`: image registration, sparse Lucas-Kanade optical flow of background
  corners (the node circles masked out) and a RANSAC similarity (``cv2.estimateAffinePartial2D``).

Both give a (3, 3) homography mapping pixels of the previous frame to the current one.

References
----------
.. [1] N. Aharon, R. Orfaig, B.-Z. Bobrovsky, "BoT-SORT: Robust associations multi-pedestrian
   tracking", arXiv:2206.14651, 2022.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import cv2
import numpy as np

from agents.perception.hough import to_grey
from agents.perception.types import Circle

__all__ = ["odometry_homography", "FlowConfig", "FlowRegistration"]


def _rot_z(theta: float) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def odometry_homography(K: np.ndarray, cam_in_root: np.ndarray, dtheta: float) -> np.ndarray:
    """Image homography (previous -> current frame) of the camera rotation caused by a root yaw.

    Parameters
    ----------
    K : ndarray, shape (3, 3)
        Pinhole intrinsics.
    cam_in_root : ndarray, shape (3, 3)
        Rotation of the camera frame in the root horizontal frame H_r (columns: camera axes in H_r).
    dtheta : float
        Yaw of the root at this step in the root at the previous step (the log's ``dtheta``), rad.

    Returns
    -------
    ndarray, shape (3, 3)
        H with ``p_cur ~ H p_prev`` for pixels of static, distant points.
    """
    Rc = np.asarray(cam_in_root, dtype=float)
    # camera k in camera k-1: Rc^T Rz(dtheta) Rc; a direction d seen in camera k-1 is R^T d in k
    R = Rc.T @ _rot_z(dtheta) @ Rc
    K = np.asarray(K, dtype=float)
    return K @ R.T @ np.linalg.inv(K)


@dataclass(frozen=True)
class FlowConfig:
    """Parameters of :class:`FlowRegistration`: working scale, corner count and quality, smallest
    corner spacing (px at the working scale), RANSAC threshold (px at full scale), and the fewest
    inliers for an answer.

    A quarter-resolution image is enough for a frame-to-frame similarity (on rendered table1 frames
    it agrees with the odometry homography as well as half resolution does, at a quarter of the
    cost: 1.8 against 6.3 ms per 1024 x 768 frame). 120 corners agree with the odometry homography
    as well as 200 did (median 2.1 px at the frame's centre and corners, p90 3.2 against 3.4 px) at
    0.65 ms less per frame; 80 drift (p90 4.4 px).
    """

    scale: float = 0.25
    max_corners: int = 120
    quality: float = 0.01
    min_distance: int = 4
    ransac_px: float = 2.0
    min_inliers: int = 12


class FlowRegistration:
    """Frame-to-frame registration from background optical flow (stateful: keeps the last frame)."""

    def __init__(self, config: FlowConfig | None = None):
        self.config = config or FlowConfig()
        self._prev: np.ndarray | None = None
        self._prev_mask: np.ndarray | None = None

    def reset(self) -> None:
        self._prev = None
        self._prev_mask = None

    def _small(self, image: np.ndarray, circles: Sequence[Circle]) -> tuple[np.ndarray, np.ndarray]:
        s = self.config.scale
        grey = to_grey(np.asarray(image))
        small = cv2.resize(grey, None, fx=s, fy=s, interpolation=cv2.INTER_AREA) if s != 1.0 else grey
        mask = np.full(small.shape, 255, np.uint8)
        for c in circles:  # the nodes move by themselves: only the background tells the camera motion
            cv2.circle(mask, (int(round(c.u * s)), int(round(c.v * s))), int(np.ceil(c.r * s * 1.2)) + 2, 0, -1)
        return small, mask

    def __call__(self, image: np.ndarray, circles: Sequence[Circle] = ()) -> np.ndarray | None:
        """Homography (3, 3) from the previous frame given to this one, or None (first frame, too
        little texture, or no consistent motion)."""
        cfg = self.config
        small, mask = self._small(image, circles)
        prev, prev_mask = self._prev, self._prev_mask
        self._prev, self._prev_mask = small, mask
        if prev is None or prev.shape != small.shape:
            return None
        pts = cv2.goodFeaturesToTrack(prev, cfg.max_corners, cfg.quality, cfg.min_distance, mask=prev_mask)
        if pts is None or len(pts) < cfg.min_inliers:
            return None
        nxt, status, _ = cv2.calcOpticalFlowPyrLK(prev, small, pts, None, winSize=(15, 15), maxLevel=2)
        good = status.ravel() == 1
        if good.sum() < cfg.min_inliers:
            return None
        A, inl = cv2.estimateAffinePartial2D(
            pts[good], nxt[good], method=cv2.RANSAC, ransacReprojThreshold=cfg.ransac_px * cfg.scale
        )
        if A is None or inl is None or int(inl.sum()) < cfg.min_inliers:
            return None
        S = np.diag([cfg.scale, cfg.scale, 1.0])
        H = np.vstack([A, [0.0, 0.0, 1.0]])
        return np.linalg.inv(S) @ H @ S
