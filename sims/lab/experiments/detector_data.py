"""Training data for the learned circle detector: rendered frames and their circles, as npz shards.

Sources, each with exact truth and reproducible from its seeds:

- ``varied``: :func:`sims.lab.experiments.varied_scenes.sequence` scenes (floors of several kinds,
  spheres coloured close to the floor, highlights, occlusion, smear), scene seeds from
  :data:`TRAIN_VARIED_SEEDS` upwards. The held-out scenes (:data:`~sims.lab.experiments.varied_scenes.HELD_OUT_SEEDS`)
  are refused.
- ``hard``: :func:`sims.lab.experiments.hard_scenes.hard_sequence` scenes (near and large spheres,
  spheres cut by the frame's edge, clumps of spheres hiding one another, rescaled, tinted and
  patched floors, dim to harsh light), seeds from :data:`TRAIN_HARD_SEEDS` upwards.
- ``pairs``: :func:`sims.lab.experiments.hard_scenes.pair_sequence` scenes (small spheres in touching or
  overlapping groups of two or three, on the harder scenes' floors and light), seeds from
  :data:`TRAIN_PAIR_SEEDS` upwards.
- ``overlap``: :func:`sims.lab.experiments.hard_scenes.overlap_sequence` scenes (groups of spheres of
  unequal sizes, 20-90 px: a large sphere partly hidden behind a smaller one), seeds from
  :data:`TRAIN_OVERLAP_SEEDS` upwards.
- ``mottled``: :func:`sims.lab.experiments.mottled_scenes.mottled_frames` (tagged discs on blotchy floors
  of many blotch sizes and tints, a quarter of the frames without any disc), seeds from
  :data:`TRAIN_MOTTLED_SEEDS` upwards; the held-out ones
  (:data:`~sims.lab.experiments.mottled_scenes.HELD_OUT_MOTTLED_SEEDS`) are refused.
- ``table1``: the 3-D renderer's ``table1`` scenario (tower assemblies on a table), simulation and
  render seeds from :data:`TRAIN_TABLE1_SEEDS` upwards (the experiments and benchmarks use seeds
  0-9).
- ``ring``: the 3-D renderer's ``multi`` scenario (cameras at the spheres' height, so spheres stand on
  the horizon against the wall behind them), each seed drawing its own ring (3-8 assemblies, spacing,
  chords), wall colour and brightness, and light; seeds from :data:`TRAIN_RING_SEEDS` upwards (the
  experiments and benchmarks render seeds 0-9 with the default wall).

A shard (``<source>-<seed>.npz``) holds, for ``n`` frames and ``m`` circles in all:

- ``images`` (n, H, W, 3) uint8 BGR, each frame resized to the network's input (``--input-size``,
  default the shipped network's: :func:`agents.perception.learned.model_input_size`);
- ``scale`` (n,) float: full-resolution pixels per input pixel;
- ``circles`` (m, 5) float32: frame index, u, v, r (silhouette circle, full-resolution pixels) and the
  visible fraction of the disc;
- ``crops`` (m, 64, 64, 3) uint8: a square crop of the full-resolution frame centred on each circle,
  4 radii wide (:func:`agents.perception.crops.crop_circle`): the second stage's training data.

(:mod:`agents.perception.training.data`.) ``python -m sims.lab.experiments.detector_data OUTDIR --varied 2000:2100``
renders a range of seeds (see ``--help``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from agents.perception.training.data import shard_from_frames, write_shard
from decentral.errors import InputError
from sims.lab.experiments.varied_scenes import HELD_OUT_SEEDS, sequence

__all__ = ["TRAIN_HARD_SEEDS", "TRAIN_MOTTLED_SEEDS", "TRAIN_OVERLAP_SEEDS", "TRAIN_PAIR_SEEDS", "TRAIN_RING_SEEDS", "TRAIN_TABLE1_SEEDS",
           "TRAIN_VARIED_SEEDS", "hard_shard", "mottled_shard", "overlap_shard", "pair_shard", "ring_shard", "table1_shard",
           "varied_shard"]

#: first scene seed of the varied training scenes (0-31 tuned the hand-made detectors, 1000-1007 held out)
TRAIN_VARIED_SEEDS = 2000
#: first seed of the harder training scenes (:mod:`sims.lab.experiments.hard_scenes`; its own generator)
TRAIN_HARD_SEEDS = 5000
#: first seed of the small-sphere group scenes (:func:`sims.lab.experiments.hard_scenes.pair_sequence`)
TRAIN_PAIR_SEEDS = 8000
#: first seed of the unequal-size group scenes (:func:`sims.lab.experiments.hard_scenes.overlap_sequence`)
TRAIN_OVERLAP_SEEDS = 8200
#: first seed of the mottled-floor training scenes (:mod:`sims.lab.experiments.mottled_scenes`)
TRAIN_MOTTLED_SEEDS = 6000
#: first seed of the table1 training runs (the experiments and benchmarks use 0-9)
TRAIN_TABLE1_SEEDS = 100
#: first seed of the ring training runs (the ``multi`` scenario; the experiments and benchmarks use 0-9)
TRAIN_RING_SEEDS = 300


def varied_shard(seed: int, frames: int, **kw) -> dict[str, np.ndarray]:
    """A shard of ``frames`` frames of varied scene ``seed`` (never a held-out scene)."""
    if seed in HELD_OUT_SEEDS:
        raise InputError(f"scene {seed} is held out for evaluation; choose another seed", field="seed")
    seq = sequence(seed, frames)
    return shard_from_frames(((f.image, [(s.u, s.v, s.r, vis) for s, vis in zip(f.spheres, f.visible)])
                              for f in seq), **kw)


def hard_shard(seed: int, frames: int, **kw) -> dict[str, np.ndarray]:
    """A shard of ``frames`` frames of harder scene ``seed`` (:func:`~sims.lab.experiments.hard_scenes.hard_sequence`)."""
    from sims.lab.experiments.hard_scenes import hard_sequence

    return shard_from_frames(((f.image, [(s.u, s.v, s.r, vis) for s, vis in zip(f.spheres, f.visible)])
                              for f in hard_sequence(seed, frames)), **kw)


def pair_shard(seed: int, frames: int, **kw) -> dict[str, np.ndarray]:
    """A shard of ``frames`` frames of small-sphere group scene ``seed``
    (:func:`~sims.lab.experiments.hard_scenes.pair_sequence`)."""
    from sims.lab.experiments.hard_scenes import pair_sequence

    return shard_from_frames(((f.image, [(s.u, s.v, s.r, vis) for s, vis in zip(f.spheres, f.visible)])
                              for f in pair_sequence(seed, frames)), **kw)


def overlap_shard(seed: int, frames: int, **kw) -> dict[str, np.ndarray]:
    """A shard of ``frames`` frames of unequal-size group scene ``seed``
    (:func:`~sims.lab.experiments.hard_scenes.overlap_sequence`)."""
    from sims.lab.experiments.hard_scenes import overlap_sequence

    return shard_from_frames(((f.image, [(s.u, s.v, s.r, vis) for s, vis in zip(f.spheres, f.visible)])
                              for f in overlap_sequence(seed, frames)), **kw)


def mottled_shard(seed: int, frames: int, **kw) -> dict[str, np.ndarray]:
    """A shard of ``frames`` frames of mottled scene ``seed`` (never a held-out one)."""
    from sims.lab.experiments.mottled_scenes import HELD_OUT_MOTTLED_SEEDS, mottled_frames

    if seed in HELD_OUT_MOTTLED_SEEDS:
        raise InputError(f"mottled scene {seed} is held out for evaluation; choose another seed", field="seed")
    return shard_from_frames(((f.image, [(*c, vis) for c, vis in zip(f.circles, f.visible)])
                              for f in mottled_frames(seed, frames)), **kw)


def table1_shard(seed: int, steps: int, *, scenario: str = "table1", **kw) -> dict[str, np.ndarray]:
    """A shard of every camera's frames of the ``scenario`` run ``seed`` (``steps`` steps)."""
    from sims.simulation.render.renderer import RenderConfig
    from sims.simulation.scenarios import get_scenario, simulate

    return _rendered_shard(simulate(get_scenario(scenario, steps=steps), seed=seed), seed, RenderConfig(), **kw)


def _rendered_shard(sim, seed: int, render, **kw) -> dict[str, np.ndarray]:
    """A shard of every camera's frames of simulation ``sim`` rendered with ``render`` (render seed ``seed``),
    each circle the exact silhouette's with its visible fraction."""
    from sims.simulation.render.frame_files import render_frames

    return shard_from_frames(((fr.image, [(nd["su"], nd["sv"], nd["sr"], nd["visible"]) for nd in fr.nodes])
                              for _, _, fr in render_frames(sim, seed, render)), **kw)


def ring_shard(seed: int, steps: int, **kw) -> dict[str, np.ndarray]:
    """A shard of every camera's frames of ring run ``seed`` (``steps`` steps of a ``multi`` ring).

    The seed draws the ring (3-8 assemblies 1.2-2.2 m apart, chords or none), the wall behind the
    horizon (brightness 0.25-0.95 at the top, darker or equal at the bottom; a tint) and the light.
    """
    from sims.simulation.render.renderer import RenderConfig
    from sims.simulation.scenarios import get_scenario, simulate

    if seed < TRAIN_RING_SEEDS:
        raise InputError(f"ring runs below {TRAIN_RING_SEEDS} are the experiments' and benchmarks'; choose another",
                         field="seed")
    rng = np.random.default_rng(seed)
    n = int(rng.integers(3, 9))
    scenario = get_scenario("multi", steps=steps, n_assemblies=n, spacing=float(rng.uniform(1.2, 2.2)),
                            chord_every=int(rng.choice([0, 0, 2, 3])) if n > 3 else 0)
    top = float(rng.uniform(0.25, 0.95))
    render = RenderConfig(wall_levels=(top, top * float(rng.uniform(0.7, 1.0))),
                          wall_tint=tuple(float(x) for x in rng.uniform(0.7, 1.0, 3)),
                          light=(float(rng.uniform(-0.6, 0.6)), float(rng.uniform(-0.6, 0.6)), 1.0))
    return _rendered_shard(simulate(scenario, seed=seed), seed, render, **kw)


def _range(text: str) -> range:
    try:
        a, b = (int(x) for x in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected FIRST:STOP, got {text!r}") from None
    return range(a, b)


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT, got {text!r}") from None
    if w < 32 or h < 32 or w * 3 != h * 4:
        raise argparse.ArgumentTypeError(f"expected a 4:3 size of at least 32 px, e.g. 384x288, got {text!r}")
    return w, h


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description="Render training shards for the learned circle detector.")
    ap.add_argument("outdir")
    ap.add_argument("--varied", type=_range, default=range(0), help="varied scene seeds FIRST:STOP")
    ap.add_argument("--varied-frames", type=int, default=10, help="frames per varied scene (default 10)")
    ap.add_argument("--hard", type=_range, default=range(0), help="harder scene seeds FIRST:STOP")
    ap.add_argument("--hard-frames", type=int, default=10, help="frames per harder scene (default 10)")
    ap.add_argument("--pairs", type=_range, default=range(0), help="small-sphere group scene seeds FIRST:STOP")
    ap.add_argument("--pairs-frames", type=int, default=10, help="frames per group scene (default 10)")
    ap.add_argument("--overlap", type=_range, default=range(0), help="unequal-size group scene seeds FIRST:STOP")
    ap.add_argument("--overlap-frames", type=int, default=10, help="frames per unequal-size group scene (default 10)")
    ap.add_argument("--mottled", type=_range, default=range(0), help="mottled-floor scene seeds FIRST:STOP")
    ap.add_argument("--mottled-frames", type=int, default=10, help="frames per mottled scene (default 10)")
    ap.add_argument("--table1", type=_range, default=range(0), help="table1 run seeds FIRST:STOP")
    ap.add_argument("--table1-steps", type=int, default=30, help="steps per table1 run (default 30)")
    ap.add_argument("--ring", type=_range, default=range(0), help="ring (multi scenario) run seeds FIRST:STOP")
    ap.add_argument("--ring-steps", type=int, default=6, help="steps per ring run (default 6)")
    ap.add_argument("--input-size", type=_size, default=None, metavar="WxH",
                    help="the frames' size in the shards: the proposal network's input (default: the shipped network's)")
    ap.add_argument("--stride", type=int, default=1, help="render every STRIDE-th seed of the ranges ...")
    ap.add_argument("--offset", type=int, default=0, help="... starting at OFFSET (parallel workers)")
    args = ap.parse_args(argv)
    if args.input_size is None:
        from agents.perception.learned import MODEL_DIR, model_input_size

        args.input_size = model_input_size(MODEL_DIR / "circles.onnx")
    kw = {"input_size": args.input_size}
    out = Path(args.outdir)
    out.mkdir(parents=True, exist_ok=True)
    jobs = [("varied", s) for s in args.varied] + [("hard", s) for s in args.hard] + \
        [("pairs", s) for s in args.pairs] + [("overlap", s) for s in args.overlap] + \
        [("mottled", s) for s in args.mottled] + [("table1", s) for s in args.table1] + \
        [("ring", s) for s in args.ring]
    for i, (kind, seed) in enumerate(jobs):
        if i % args.stride != args.offset:
            continue
        path = out / f"{kind}-{seed}.npz"
        if path.exists():
            continue
        try:
            if kind == "varied":
                arrays = varied_shard(seed, args.varied_frames, **kw)
            elif kind == "hard":
                arrays = hard_shard(seed, args.hard_frames, **kw)
            elif kind == "pairs":
                arrays = pair_shard(seed, args.pairs_frames, **kw)
            elif kind == "overlap":
                arrays = overlap_shard(seed, args.overlap_frames, **kw)
            elif kind == "mottled":
                arrays = mottled_shard(seed, args.mottled_frames, **kw)
            elif kind == "ring":
                arrays = ring_shard(seed, args.ring_steps, **kw)
            else:
                arrays = table1_shard(seed, args.table1_steps, **kw)
        except InputError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        write_shard(path, arrays)
        print(f"{path}: {len(arrays['images'])} frames, {len(arrays['circles'])} circles", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
