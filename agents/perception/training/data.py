"""Training data of the learned circle detector: shards, targets and augmentation (numpy and OpenCV).

A **shard** is an ``.npz`` file of ``n`` frames and ``m`` circles:

- ``images`` (n, H, W, 3) uint8 BGR, each frame resized to the network's input (256 x 192 by default);
- ``scale`` (n,) float32: full-resolution pixels per input pixel;
- ``circles`` (m, 5) float32: frame index, u, v, r (the sphere's silhouette circle, full-resolution
  pixels, OpenCV's pixel centres) and the visible fraction of its disc (1 if unknown);
- ``crops`` (m, 64, 64, 3) uint8: :func:`agents.perception.crops.crop_circle` of each circle on the
  full-resolution frame (the second stage's data).

:func:`shard_from_frames` builds one from any frames and circles (rendered scenes:
``sims.lab.experiments.detector_data``; a user's own labelled frames: :func:`shard_from_labels`).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from agents.perception.crops import CROP_SIZE, crop_circle, refine_input
from decentral.errors import InputError

__all__ = [
    "INPUT_SIZE",
    "MIN_VISIBLE",
    "STRIDE",
    "Shards",
    "detector_batch",
    "detector_targets",
    "frame_record",
    "load_shards",
    "refine_batch",
    "shard_from_frames",
    "shard_from_labels",
    "to_input",
    "write_shard",
]

#: the default input (width, height) of :func:`shard_from_frames` (the first releases' networks; the command-line
#: tools default to the shipped network's, :func:`agents.perception.learned.model_input_size`) and the output
#: stride (input pixels per heatmap cell)
INPUT_SIZE = (256, 192)
STRIDE = 4
#: spheres showing less than this fraction of their disc are neither positives nor negatives
MIN_VISIBLE = 0.3


def frame_record(image: np.ndarray, circles: np.ndarray, *, input_size: tuple[int, int] = INPUT_SIZE,
                 crop: int = CROP_SIZE) -> tuple[np.ndarray, float, np.ndarray]:
    """One frame's record: the input-sized image, full-resolution pixels per input pixel, the circles' crops.

    ``image`` is (H, W, 3) uint8 BGR of the input's aspect ratio; ``circles`` (m, 3) u, v, r in its pixels.
    """
    if image.ndim != 3 or image.shape[2] != 3:
        raise InputError("expected a colour (H, W, 3) frame", field="image")
    h, w = image.shape[:2]
    iw, ih = input_size
    if abs(w * ih - h * iw) > 1e-6 * w * ih:
        raise InputError(f"frame {w}x{h} does not have the input's aspect ratio {iw}x{ih}", field="image")
    small = cv2.resize(image, (iw, ih), interpolation=cv2.INTER_AREA)
    crops = np.stack([crop_circle(image, u, v, r, crop) for u, v, r in circles]) if len(circles) else \
        np.zeros((0, crop, crop, 3), np.uint8)
    return small, w / iw, crops


def shard_from_frames(frames, *, input_size=INPUT_SIZE, crop: int = CROP_SIZE) -> dict[str, np.ndarray]:
    """A shard's arrays from ``frames``: an iterable of (image, circles (m, 4): u, v, r, visible)."""
    images, scales, circles, crops = [], [], [], []
    for k, (image, truth) in enumerate(frames):
        truth = np.asarray(truth, float).reshape(-1, 4)
        small, scale, cr = frame_record(image, truth[:, :3], input_size=input_size, crop=crop)
        images.append(small)
        scales.append(scale)
        circles.append(np.column_stack([np.full(len(truth), k), truth]))
        crops.append(cr)
    if not images:
        raise InputError("no frames", field="frames")
    return {"images": np.stack(images), "scale": np.asarray(scales, np.float32),
            "circles": np.concatenate(circles).astype(np.float32),
            "crops": np.concatenate(crops)}


def shard_from_labels(labels: str | os.PathLike, **kw) -> dict[str, np.ndarray]:
    """A shard of a user's own labelled frames.

    ``labels`` is a JSON file ``{"frames": [{"image": "f0001.png", "circles": [[u, v, r], ...]}, ...]}``
    (image paths relative to the file; circles in the image's pixels, every sphere in the frame; an
    optional fourth value per circle is its visible fraction). Bad files end in an
    :class:`~decentral.errors.InputError` naming the file and field.
    """
    path = Path(labels)
    try:
        doc = json.loads(path.read_text())
        entries = doc["frames"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise InputError(f"cannot read labelled frames ({exc.__class__.__name__}: {exc})", source=str(path)) from None

    def frames():
        for i, entry in enumerate(entries):
            try:
                name = entry["image"]
                circles = np.asarray(entry["circles"], float)
                circles = circles.reshape(-1, circles.shape[-1] if circles.size else 3)
            except (KeyError, TypeError, ValueError):
                raise InputError("each frame needs 'image' and 'circles' [[u, v, r], ...]",
                                 source=str(path), field=f"frames[{i}]") from None
            if circles.shape[1] == 3:
                circles = np.column_stack([circles, np.ones(len(circles))])
            if circles.shape[1] != 4 or not np.isfinite(circles).all() or (circles[:, 2] <= 0).any():
                raise InputError("circles must be [u, v, r] or [u, v, r, visible] with r > 0",
                                 source=str(path), field=f"frames[{i}].circles")
            image = cv2.imread(str(path.parent / name), cv2.IMREAD_COLOR)
            if image is None:
                raise InputError("cannot read the image", source=str(path.parent / name))
            yield image, circles
    return shard_from_frames(frames(), **kw)


def write_shard(path: str | os.PathLike, arrays: dict[str, np.ndarray]) -> None:
    """Write a shard (compressed npz) whole or not at all (a temporary file renamed)."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.part")
    try:
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, **arrays)
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise InputError(f"cannot write the shard ({exc.strerror})", source=str(path)) from None


@dataclass
class Shards:
    """Shards loaded in memory.

    ``images`` (N, H, W, 3) uint8; ``scale`` (N,); ``circles`` (M, 5) with the frame index into
    ``images``; ``crops`` (M, 64, 64, 3) uint8; ``first`` (N + 1,) index of each frame's first
    circle (circles are sorted by frame).
    """

    images: np.ndarray
    scale: np.ndarray
    circles: np.ndarray
    crops: np.ndarray
    first: np.ndarray

    def frame_circles(self, k: int) -> np.ndarray:
        """Frame ``k``'s circles (m, 4): u, v, r in input pixels and the visible fraction."""
        c = self.circles[self.first[k]:self.first[k + 1], 1:5].astype(np.float64).copy()
        c[:, :3] /= self.scale[k]
        return c


def load_shards(paths) -> Shards:
    """Concatenate the shards at ``paths`` (in the order given)."""
    images, scale, circles, crops = [], [], [], []
    n = 0
    for p in paths:
        try:
            with np.load(p) as z:
                im, sc, ci, cr = z["images"], z["scale"], z["circles"], z["crops"]
        except (OSError, ValueError, KeyError) as exc:
            raise InputError(f"not a training shard ({exc.__class__.__name__}: {exc})", source=str(p)) from None
        ci = ci.copy()
        ci[:, 0] += n
        n += len(im)
        images.append(im)
        scale.append(sc)
        circles.append(ci)
        crops.append(cr)
    if not images:
        raise InputError("no training shards given", field="shards")
    circles = np.concatenate(circles)
    order = np.argsort(circles[:, 0], kind="stable")
    circles = circles[order]
    first = np.searchsorted(circles[:, 0], np.arange(n + 1))
    return Shards(np.concatenate(images), np.concatenate(scale), circles, np.concatenate(crops)[order], first)


def detector_targets(circles: np.ndarray, out_hw: tuple[int, int], stride: int = STRIDE,
                     min_visible: float = MIN_VISIBLE) -> tuple[np.ndarray, ...]:
    """The heatmap network's targets for one frame.

    Parameters
    ----------
    circles : ndarray, shape (m, 4)
        u, v, r in input pixels, visible fraction.
    out_hw : (h, w)
        The output grid (input size / stride).

    Returns
    -------
    heat : (h, w) float32
        Gaussian peaks (sigma = max(0.7, r / (3 stride)) cells) at the centres of spheres showing
        at least ``min_visible`` of their disc with the centre inside the frame.
    weight : (h, w) float32
        0 within the disc of a sphere that shows less (neither positive nor negative), else 1.
    reg : (4, h, w) float32
        At each positive centre cell: log radius (input pixels), the centre's offset (x, y) in cells
        from the cell's centre, and 1 (the regression mask).
    """
    h, w = out_hw
    heat = np.zeros((h, w), np.float32)
    weight = np.ones((h, w), np.float32)
    reg = np.zeros((4, h, w), np.float32)
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    for u, v, r, vis in circles:
        cx, cy = (u + 0.5) / stride - 0.5, (v + 0.5) / stride - 0.5  # centre in cells (cell centres at integers)
        inside = -0.5 <= cx < w - 0.5 and -0.5 <= cy < h - 0.5
        if vis < min_visible or not inside:
            weight[(xs - cx) ** 2 + (ys - cy) ** 2 <= (r / stride + 1.0) ** 2] = 0.0
            continue
        sigma = max(0.7, r / stride / 3.0)
        heat = np.maximum(heat, np.exp(-((xs - cx) ** 2 + (ys - cy) ** 2) / (2 * sigma ** 2)))
        ix, iy = int(round(cx)), int(round(cy))
        ix, iy = min(max(ix, 0), w - 1), min(max(iy, 0), h - 1)
        heat[iy, ix] = 1.0
        reg[:, iy, ix] = (np.log(r), cx - ix, cy - iy, 1.0)
    weight = np.maximum(weight, (heat > 0.5).astype(np.float32))
    return heat, weight, reg


def _augment(img: np.ndarray, circles: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Flips, colour-channel permutation, gain and contrast per channel, noise."""
    h, w = img.shape[:2]
    c = circles.copy()
    if rng.random() < 0.5:
        img = img[:, ::-1]
        c[:, 0] = w - 1 - c[:, 0]
    if rng.random() < 0.5:
        img = img[::-1]
        c[:, 1] = h - 1 - c[:, 1]
    img = img[:, :, rng.permutation(3)].astype(np.float32)
    gain = rng.uniform(0.75, 1.25) * rng.uniform(0.9, 1.1, 3)
    mean = img.mean(axis=(0, 1))
    img = (img - mean) * rng.uniform(0.8, 1.2) + mean * gain
    if rng.random() < 0.5:
        img += rng.standard_normal(img.shape, dtype=np.float32) * np.float32(rng.uniform(0, 6))
    return np.clip(img, 0, 255), c


def to_input(images: np.ndarray) -> np.ndarray:
    """uint8 or float (N, H, W, 3) BGR in 0-255 -> float32 (N, 3, H, W) in [-0.5, 0.5] (the networks' input)."""
    return (np.asarray(images, np.float32).transpose(0, 3, 1, 2) * np.float32(1 / 255.0) - np.float32(0.5))


def detector_batch(data: Shards, frames: np.ndarray, rng: np.random.Generator | None,
                   stride: int = STRIDE) -> tuple[np.ndarray, ...]:
    """Inputs (B, 3, H, W), heat (B, 1, h, w), weight (B, 1, h, w), reg (B, 4, h, w); augmented when ``rng`` is given."""
    h, w = data.images.shape[1] // stride, data.images.shape[2] // stride
    xs, heats, weights, regs = [], [], [], []
    for k in frames:
        img, c = data.images[k], data.frame_circles(int(k))
        if rng is not None:
            img, c = _augment(img, c, rng)
        heat, weight, reg = detector_targets(c, (h, w), stride)
        xs.append(img)
        heats.append(heat)
        weights.append(weight)
        regs.append(reg)
    return to_input(np.stack(xs)), np.stack(heats)[:, None], np.stack(weights)[:, None], np.stack(regs)


def refine_batch(data: Shards, idx: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Second-stage inputs (B, 3, 32, 32) and targets (B, 3) from circles ``idx``, with random proposals.

    A proposal is the true circle moved by up to 0.3 r and scaled by 0.77-1.3; the target is the true
    circle relative to the proposal: ((u - u_p) / r_p, (v - v_p) / r_p, log(r / r_p)).
    """
    xs, ys = [], []
    for i in idx:
        d = np.clip(rng.normal(0.0, 0.12, 2), -0.3, 0.3)
        s = float(np.exp(np.clip(rng.normal(0.0, 0.1), np.log(0.77), np.log(1.3))))
        crop = data.crops[i]
        if rng.random() < 0.5:  # a flipped crop is a flipped circle
            crop = crop[:, ::-1]
        if rng.random() < 0.5:
            crop = crop[::-1]
        x = refine_input(np.ascontiguousarray(crop[:, :, rng.permutation(3)]), d[0], d[1], s).astype(np.float32)
        x = x * np.float32(rng.uniform(0.8, 1.2)) + np.float32(rng.uniform(-20, 20))
        if rng.random() < 0.5:
            x += rng.standard_normal(x.shape, dtype=np.float32) * np.float32(rng.uniform(0, 6))
        xs.append(np.clip(x, 0, 255))
        ys.append((-d[0] / s, -d[1] / s, -np.log(s)))
    return to_input(np.stack(xs)), np.asarray(ys, np.float32)

