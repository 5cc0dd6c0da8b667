"""``decentral train-detector``: retrain the learned circle detector on rendered scenes and/or labelled frames.

Renders the training shards that are not yet in ``OUT/shards`` (varied scenes, harder scenes,
mottled floors, ``table1`` runs and ring runs (the ``multi`` scenario's low cameras) by seed, :mod:`sims.lab.experiments.detector_data`; the held-out
scenes are refused), adds shards of the user's own labelled frames (``--labels``, see
:func:`agents.perception.training.data.shard_from_labels`), then trains both networks on the CPU
(``python -m agents.perception.training train``; PyTorch from the ``train`` extra; on a CUDA GPU
where torch finds one) and writes ``OUT/circles.onnx``, ``OUT/circle_refine.onnx`` and their loss
curves, and the second stage's 8-bit copy ``OUT/circle_refine_int8.onnx``
(``python -m agents.perception.training quantize``), which the detector runs with onnxruntime. Use
the result with ``LearnedConfig(model=OUT/"circles.onnx", refine_model=OUT/"circle_refine.onnx")``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from decentral.errors import InputError

__all__ = ["HELP", "add_arguments", "run"]

HELP = "retrain the learned circle detector (rendered scenes and/or your labelled frames) -> ONNX"


def _range(text: str) -> range:
    try:
        a, b = (int(x) for x in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected FIRST:STOP, got {text!r}") from None
    return range(a, b)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("out", metavar="OUT", type=Path, help="output folder (shards in OUT/shards, models in OUT)")
    parser.add_argument("--varied", type=_range, default=range(2000, 2300), metavar="FIRST:STOP",
                        help="varied scene seeds to render (default: 2000:2300)")
    parser.add_argument("--varied-frames", type=int, default=10, help="frames per varied scene (default: 10)")
    parser.add_argument("--hard", type=_range, default=range(5000, 5200), metavar="FIRST:STOP",
                        help="harder scene seeds to render (near, far, edge-cut, clumped spheres; default: 5000:5200)")
    parser.add_argument("--mottled", type=_range, default=range(6000, 6100), metavar="FIRST:STOP",
                        help="mottled-floor scene seeds to render (tagged discs on blotchy floors; default: 6000:6100)")
    parser.add_argument("--table1", type=_range, default=range(100, 109), metavar="FIRST:STOP",
                        help="table1 run seeds to render (default: 100:109)")
    parser.add_argument("--table1-steps", type=int, default=30, help="steps per table1 run (default: 30)")
    parser.add_argument("--ring", type=_range, default=range(300, 370), metavar="FIRST:STOP",
                        help="ring run seeds to render (multi scenario: spheres on the horizon against a wall of "
                             "varied colour; default: 300:370)")
    parser.add_argument("--ring-steps", type=int, default=6, help="steps per ring run (default: 6)")
    parser.add_argument("--labels", type=Path, nargs="*", default=[], metavar="LABELS.json",
                        help="your labelled frames: {\"frames\": [{\"image\": ..., \"circles\": [[u, v, r], ...]}]}")
    parser.add_argument("--steps", type=int, default=900, help="proposal network steps (default: 900)")
    parser.add_argument("--refine-steps", type=int, default=2500, help="second-stage steps (default: 2500)")
    parser.add_argument("--seed", type=int, default=0, help="training seed (default: 0)")
    parser.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto",
                        help="train on a CUDA GPU where torch finds one (auto, the default), the CPU, or the GPU")
    parser.add_argument("--input-size", default=None, metavar="WxH",
                        help="the proposal network's input (default: that of --init's network, else the shipped one's)")
    parser.add_argument("--init", type=Path, default=None, metavar="FOLDER",
                        help="fine-tune the networks in FOLDER (.pt of an earlier run, or .onnx, e.g. the shipped "
                             "agents/perception/models) instead of starting from random weights")


def run(args: argparse.Namespace) -> int:
    from agents.perception.training.__main__ import main as train_main
    from agents.perception.training.data import shard_from_labels, write_shard
    from sims.lab.experiments.detector_data import main as render_main

    shards = args.out / "shards"
    shards.mkdir(parents=True, exist_ok=True)
    if args.varied_frames < 1 or args.table1_steps < 1 or args.ring_steps < 1:
        raise InputError("--varied-frames, --table1-steps and --ring-steps must be positive", field="--varied-frames")
    render = ["--varied", f"{args.varied.start}:{args.varied.stop}", "--varied-frames", str(args.varied_frames),
              "--hard", f"{args.hard.start}:{args.hard.stop}", "--hard-frames", str(args.varied_frames),
              "--mottled", f"{args.mottled.start}:{args.mottled.stop}", "--mottled-frames", str(args.varied_frames),
              "--table1", f"{args.table1.start}:{args.table1.stop}", "--table1-steps", str(args.table1_steps),
              "--ring", f"{args.ring.start}:{args.ring.stop}", "--ring-steps", str(args.ring_steps)]
    from agents.perception.training.__main__ import _size

    size = None if args.input_size is None else "x".join(map(str, _size(args.input_size)))
    if size is None and args.init is not None and (args.init / "circles.onnx").is_file():
        from agents.perception.learned import model_input_size

        size = "x".join(map(str, model_input_size(args.init / "circles.onnx")))
    if size is not None:
        render += ["--input-size", size]
    if render_main([str(shards), *render]) != 0:
        return 2
    if size is None:
        from agents.perception.learned import MODEL_DIR, model_input_size

        size = "x".join(map(str, model_input_size(MODEL_DIR / "circles.onnx")))
    for k, labels in enumerate(args.labels):
        write_shard(shards / f"labels-{k}.npz",
                    shard_from_labels(labels, input_size=_size(size)))
    init = [] if args.init is None else ["--init", str(args.init)]
    validation = ["--validation", "varied-*9.npz", "hard-*49.npz", "mottled-*9.npz", "table1-*8.npz", "ring-*9.npz"]
    status = train_main(["train", str(shards), "-o", str(args.out), "--steps", str(args.steps),
                         "--refine-steps", str(args.refine_steps), "--seed", str(args.seed), "--device", args.device,
                         *init, *validation, "--oversample", "table1-*=2"])
    if status != 0:
        return status
    return train_main(["quantize", str(shards), "--model", str(args.out / "circle_refine.onnx"), "--seed", str(args.seed),
                       *validation])
