"""Training data for the learned circle detector: rendered frames and their circles, as npz shards.

Two sources, both with exact truth and reproducible from their seeds:

- ``varied``: :func:`sims.experiments.varied_scenes.sequence` scenes (floors of several kinds,
  spheres coloured close to the floor, highlights, occlusion, smear), scene seeds from
  :data:`TRAIN_VARIED_SEEDS` upwards. The held-out scenes (:data:`~sims.experiments.varied_scenes.HELD_OUT_SEEDS`)
  are refused.
- ``table1``: the 3-D renderer's ``table1`` scenario (tower assemblies on a table), simulation and
  render seeds from :data:`TRAIN_TABLE1_SEEDS` upwards (the experiments and benchmarks use seeds
  0-9).

A shard (``<source>-<seed>.npz``) holds, for ``n`` frames and ``m`` circles in all:

- ``images`` (n, H, W, 3) uint8 BGR, each frame resized to the network's input (default 256 x 192);
- ``scale`` (n,) float: full-resolution pixels per input pixel;
- ``circles`` (m, 5) float32: frame index, u, v, r (silhouette circle, full-resolution pixels) and the
  visible fraction of the disc;
- ``crops`` (m, C, C, 3) uint8: a square crop of the full-resolution frame centred on each circle,
  ``CROP_SPAN`` radii wide, resized to C x C (default 64): the second stage's training data.

Written by :func:`write_shard`; ``python -m sims.experiments.detector_data OUTDIR --varied 2000:2100``
renders a range of seeds (see ``--help``).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import cv2
import numpy as np

from agents.perception.crops import CROP_SIZE, CROP_SPAN, crop_circle
from decentral.errors import InputError
from sims.experiments.varied_scenes import HELD_OUT_SEEDS, sequence
from sims.io.atomic import write_atomic

__all__ = ["TRAIN_VARIED_SEEDS", "TRAIN_TABLE1_SEEDS", "CROP_SPAN", "frame_record", "varied_shard",
           "table1_shard", "write_shard", "shard_from_frames"]  # CROP_SPAN: re-exported

#: first scene seed of the varied training scenes (0-31 tuned the hand-made detectors, 1000-1007 held out)
TRAIN_VARIED_SEEDS = 2000
#: first seed of the table1 training runs (the experiments and benchmarks use 0-9)
TRAIN_TABLE1_SEEDS = 100


def frame_record(image: np.ndarray, circles: np.ndarray, *, input_size: tuple[int, int] = (256, 192),
                 crop: int = CROP_SIZE) -> tuple[np.ndarray, float, np.ndarray]:
    """One frame's training record: the input-sized image, its scale and the circles' crops.

    Parameters
    ----------
    image : ndarray, shape (H, W, 3) uint8 BGR
    circles : ndarray, shape (m, 3)
        Silhouette circles (u, v, r) in full-resolution pixels.
    input_size : (width, height)
        The network's input; the frame must have the same aspect ratio.

    Returns
    -------
    small : ndarray, shape (height, width, 3) uint8
    scale : float
        Full-resolution pixels per input pixel.
    crops : ndarray, shape (m, crop, crop, 3) uint8
    """
    h, w = image.shape[:2]
    iw, ih = input_size
    if abs(w / iw - h / ih) > 1e-6 * w:
        raise InputError(f"frame {w}x{h} does not have the input's aspect ratio {iw}x{ih}", field="image")
    small = cv2.resize(image, (iw, ih), interpolation=cv2.INTER_AREA)
    crops = np.stack([crop_circle(image, u, v, r, crop) for u, v, r in circles]) if len(circles) else \
        np.zeros((0, crop, crop, 3), np.uint8)
    return small, w / iw, crops


def shard_from_frames(frames, *, input_size=(256, 192), crop: int = CROP_SIZE) -> dict[str, np.ndarray]:
    """A shard's arrays from ``frames``: an iterable of (image, circles (m, 4): u, v, r, visible)."""
    images, scales, circles, crops = [], [], [], []
    for k, (image, truth) in enumerate(frames):
        truth = np.asarray(truth, float).reshape(-1, 4)
        small, scale, cr = frame_record(image, truth[:, :3], input_size=input_size, crop=crop)
        images.append(small)
        scales.append(scale)
        circles.append(np.column_stack([np.full(len(truth), k), truth]))
        crops.append(cr)
    return {"images": np.stack(images), "scale": np.asarray(scales, np.float32),
            "circles": np.concatenate(circles).astype(np.float32) if circles else np.zeros((0, 5), np.float32),
            "crops": np.concatenate(crops) if crops else np.zeros((0, crop, crop, 3), np.uint8)}


def varied_shard(seed: int, frames: int, **kw) -> dict[str, np.ndarray]:
    """A shard of ``frames`` frames of varied scene ``seed`` (never a held-out scene)."""
    if seed in HELD_OUT_SEEDS:
        raise InputError(f"scene {seed} is held out for evaluation; choose another seed", field="seed")
    seq = sequence(seed, frames)
    return shard_from_frames(((f.image, [(s.u, s.v, s.r, vis) for s, vis in zip(f.spheres, f.visible)])
                              for f in seq), **kw)


def table1_shard(seed: int, steps: int, *, scenario: str = "table1", **kw) -> dict[str, np.ndarray]:
    """A shard of every camera's frames of the ``scenario`` run ``seed`` (``steps`` steps)."""
    from sims.render.frames import render_frames
    from sims.render.renderer import RenderConfig
    from sims.scenarios import get_scenario, simulate

    sim = simulate(get_scenario(scenario, steps=steps), seed=seed)
    return shard_from_frames(((fr.image, [(n["su"], n["sv"], n["sr"], n["visible"]) for n in fr.nodes])
                              for _, _, fr in render_frames(sim, seed, RenderConfig())), **kw)


def write_shard(path: str | os.PathLike, arrays: dict[str, np.ndarray]) -> None:
    """Write a shard whole or not at all (compressed npz)."""
    write_atomic(Path(path), lambda fh: np.savez_compressed(fh, **arrays), binary=True)


def _range(text: str) -> range:
    try:
        a, b = (int(x) for x in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected FIRST:STOP, got {text!r}") from None
    return range(a, b)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description="Render training shards for the learned circle detector.")
    ap.add_argument("outdir")
    ap.add_argument("--varied", type=_range, default=range(0), help="varied scene seeds FIRST:STOP")
    ap.add_argument("--varied-frames", type=int, default=10, help="frames per varied scene (default 10)")
    ap.add_argument("--table1", type=_range, default=range(0), help="table1 run seeds FIRST:STOP")
    ap.add_argument("--table1-steps", type=int, default=30, help="steps per table1 run (default 30)")
    ap.add_argument("--stride", type=int, default=1, help="render every STRIDE-th seed of the ranges ...")
    ap.add_argument("--offset", type=int, default=0, help="... starting at OFFSET (parallel workers)")
    args = ap.parse_args(argv)
    out = Path(args.outdir)
    out.mkdir(parents=True, exist_ok=True)
    jobs = [("varied", s) for s in args.varied] + [("table1", s) for s in args.table1]
    for i, (kind, seed) in enumerate(jobs):
        if i % args.stride != args.offset:
            continue
        path = out / f"{kind}-{seed}.npz"
        if path.exists():
            continue
        try:
            arrays = varied_shard(seed, args.varied_frames) if kind == "varied" else table1_shard(seed, args.table1_steps)
        except InputError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        write_shard(path, arrays)
        print(f"{path}: {len(arrays['images'])} frames, {len(arrays['circles'])} circles", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
