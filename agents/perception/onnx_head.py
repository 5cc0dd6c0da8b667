"""A user's own learned circle detector (a CircleNet-style head [1]_) loaded from ONNX with ``cv2.dnn``.

Liu et al. 2024 §III-A detects nodes with a YOLO network whose head predicts bounding circles. This loader
runs such a network exported to ONNX, with this output convention (CircleNet's):

- ``heatmap`` (1, 1, h, w): centre likelihood in [0, 1] on a grid of stride ``H / h`` input pixels;
- ``radius`` (1, 1, h, w): the circle radius in input pixels at each cell;
- ``offset`` (1, 2, h, w), optional: the centre's sub-cell offset (x, y) in cells.

Outputs are found by these names, else taken in this order. The input is the image resized to
``input_size`` (width, height), as float32 NCHW in [0, 1], grey (1 channel) or RGB (3). Peaks of the
heatmap (3 x 3 local maxima above ``threshold``) become circles in image pixels; with ``refine`` the
rim fit of the classical detector (:mod:`agents.perception.refine`) polishes them to sub-pixel.

References
----------
.. [1] H. Yang et al., "CircleNet: Anchor-free glomerulus detection with circle representation",
   MICCAI 2020 (Liu et al. 2024 ref. [30]).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import cv2
import numpy as np

from agents.perception.hough import suppress, to_grey
from agents.perception.refine import RefineConfig, refine_circles
from agents.perception.types import Circle
from decentral.errors import InputError

__all__ = ["OnnxHeadConfig", "OnnxCircleDetector"]


@dataclass(frozen=True)
class OnnxHeadConfig:
    """Input size (width, height), channels (1 grey or 3 RGB), peak threshold, refinement."""

    input_size: tuple[int, int] = (512, 384)
    channels: int = 3
    threshold: float = 0.5
    refine: bool = True
    refine_config: RefineConfig = field(default_factory=RefineConfig)
    max_circles: int = 64


class OnnxCircleDetector:
    """A :class:`~agents.perception.types.CircleDetector` running a circle-head network via ``cv2.dnn``."""

    def __init__(self, model_path: str | os.PathLike, config: OnnxHeadConfig | None = None):
        self.config = config or OnnxHeadConfig()
        if self.config.channels not in (1, 3):
            raise ValueError("channels must be 1 or 3")
        try:
            self.net = cv2.dnn.readNetFromONNX(str(model_path))
        except cv2.error as err:
            raise InputError(f"cannot load the ONNX model ({str(err).strip().splitlines()[-1]})", source=str(model_path)) from None
        if self.net.empty():
            raise InputError("cannot load the ONNX model", source=str(model_path))
        self.outputs = list(self.net.getUnconnectedOutLayersNames())

    def _forward(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        cfg = self.config
        img = np.asarray(image)
        if cfg.channels == 1:
            x = to_grey(img)
            blob = cv2.dnn.blobFromImage(x, 1.0 / 255.0, cfg.input_size)
        else:
            x = img if img.ndim == 3 else cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
            blob = cv2.dnn.blobFromImage(x[..., :3], 1.0 / 255.0, cfg.input_size, swapRB=True)
        self.net.setInput(blob)
        outs = self.net.forward(self.outputs)
        named = dict(zip(self.outputs, outs))
        heat = named.get("heatmap", outs[0])
        radius = named.get("radius", outs[1] if len(outs) > 1 else None)
        offset = named.get("offset", outs[2] if len(outs) > 2 else None)
        if radius is None:
            raise InputError("the ONNX model must output a heatmap and a radius map", field="outputs")
        return np.asarray(heat)[0, 0], np.asarray(radius)[0, 0], None if offset is None else np.asarray(offset)[0]

    def detect(self, image: np.ndarray) -> list[Circle]:
        """Circles from the network's peaks (optionally rim-refined), best score first."""
        cfg = self.config
        img = np.asarray(image)
        if img.size == 0:
            return []
        H, W = img.shape[:2]
        heat, radius, offset = self._forward(img)
        h, w = heat.shape
        peaks = (heat >= cfg.threshold) & (heat >= cv2.dilate(heat.astype(np.float32), np.ones((3, 3), np.uint8)))
        ys, xs = np.nonzero(peaks)
        sx, sy = cfg.input_size[0] / w, cfg.input_size[1] / h  # input pixels per cell
        ox = offset[0, ys, xs] if offset is not None else 0.0
        oy = offset[1, ys, xs] if offset is not None else 0.0
        # cell centre -> input pixel -> image pixel (pixel centres at integers)
        u_in, v_in = (xs + 0.5 + ox) * sx - 0.5, (ys + 0.5 + oy) * sy - 0.5
        kx, ky = W / cfg.input_size[0], H / cfg.input_size[1]
        circles = np.column_stack([(u_in + 0.5) * kx - 0.5, (v_in + 0.5) * ky - 0.5, radius[ys, xs] * 0.5 * (kx + ky)])
        scores = heat[ys, xs].astype(float)
        keep = np.isfinite(circles).all(axis=1) & (circles[:, 2] > 0)
        circles, scores = circles[keep], scores[keep]
        if cfg.refine and len(circles):
            fine = img.astype(np.float32) if img.ndim == 3 else to_grey(img).astype(np.float32)
            refined, rim, ok = refine_circles(fine, circles, cfg.refine_config)
            circles = np.where(ok[:, None], refined, circles)
        found = [Circle(float(u), float(v), float(r), float(min(max(s, 0.0), 1.0))) for (u, v, r), s in zip(circles, scores)]
        return suppress(found, strong=0.0)[: cfg.max_circles]
