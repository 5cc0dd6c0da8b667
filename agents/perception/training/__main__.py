"""Command line: train the learned circle detector on shards, or make a shard of labelled frames.

``python -m agents.perception.training train SHARD_DIR -o OUT [--network detector|refine|both]
[--steps N] [--seed S] [--device auto|cpu|cuda] [--workers N] [--validation PATTERN ...]`` trains on
every ``*.npz`` in SHARD_DIR (sorted by name) except those matching a ``--validation`` pattern, which
form the validation set; writes ``OUT/circles.onnx`` and/or ``OUT/circle_refine.onnx`` with their
loss curves. The proposal network's input size is the shards' frame size.

``python -m agents.perception.training quantize SHARD_DIR --model MODEL.onnx [-o OUT.onnx]
[--samples N] [--seed S]`` writes the 8-bit copy of a second stage, calibrated on the training
shards and checked on the validation ones (:mod:`agents.perception.training.quantize`), by default
beside the model as ``<stem>_int8.onnx``, where the detector looks for it (the shipped
``circle_refine_int8.onnx`` is this of ``circle_refine.onnx``); a report ``OUT.json`` beside it.

``python -m agents.perception.training label LABELS.json SHARD.npz`` turns a user's labelled frames
(see :func:`agents.perception.training.data.shard_from_labels`) into a shard.

Rendered training shards: ``python -m sims.lab.experiments.detector_data``. Bad input ends with one
line naming the file or option and exit status 2.
"""

from __future__ import annotations

import argparse
import fnmatch
import os
import sys
from pathlib import Path

from decentral.errors import InputError


#: the default name patterns of the validation shards (seeds ending in 9)
VALIDATION = ["varied-*9.npz", "table1-*9.npz"]


def _split(folder: Path, patterns: list[str]) -> tuple[list[Path], list[Path]]:
    files = sorted(folder.glob("*.npz"))
    if not files:
        raise InputError("no *.npz shards in the folder", source=str(folder))
    val = [f for f in files if any(fnmatch.fnmatch(f.name, p) for p in patterns)]
    train = [f for f in files if f not in val]
    if not train or not val:
        raise InputError("need training and validation shards (see --validation)", source=str(folder))
    return train, val


def _size(text: str) -> tuple[int, int]:
    """``"384x288"`` -> (384, 288); anything else is an InputError naming --input-size."""
    parts = text.lower().split("x")
    if len(parts) != 2 or not all(p.isdigit() and int(p) > 0 for p in parts):
        raise InputError(f"expected WIDTHxHEIGHT, e.g. 384x288, got {text!r}", field="--input-size")
    return int(parts[0]), int(parts[1])


def _quantize(args) -> int:
    from agents.perception.learned import quantized_path
    from agents.perception.training.data import load_shards
    from agents.perception.training.quantize import quantize_refine

    train_files, val_files = _split(args.shards, args.validation)
    out = args.out if args.out is not None else quantized_path(args.model)
    report = quantize_refine(args.model, load_shards(train_files), load_shards(val_files), out,
                             samples=args.samples, seed=args.seed)
    v = report["validation"]
    print(f"{out}: {report['calibration_windows']} calibration windows; on {v['windows']} validation windows "
          f"the corrections differ by at most {max(v['max']):.4f} radii (p99 {max(v['p99']):.4f})")
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m agents.perception.training", description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="command", required=True)
    tr = sub.add_parser("train", help="train on a folder of shards")
    tr.add_argument("shards", type=Path)
    tr.add_argument("-o", "--out", type=Path, required=True)
    tr.add_argument("--network", choices=("detector", "refine", "both"), default="both")
    tr.add_argument("--steps", type=int, default=3000, help="detector steps (default: 3000)")
    tr.add_argument("--refine-steps", type=int, default=4000, help="second-stage steps (default: 4000)")
    tr.add_argument("--batch", type=int, default=24)
    tr.add_argument("--lr", type=float, default=2e-3)
    tr.add_argument("--seed", type=int, default=0)
    tr.add_argument("--eval-every", type=int, default=100)
    tr.add_argument("--warmup", type=int, default=100, help="learning-rate warm-up steps (default: 100)")
    tr.add_argument("--init", type=Path, default=None,
                    help="start from the networks in this folder (an earlier run's circles.pt / circle_refine.pt, else "
                         "the .onnx files, e.g. agents/perception/models): fine-tuning")
    tr.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto",
                    help="where to train: a CUDA GPU where torch finds one (auto, the default), the CPU, or the GPU")
    tr.add_argument("--workers", type=int, default=0,
                    help="processes preparing the batches (default 0: the training process; the result is the same)")
    tr.add_argument("--width", type=int, default=48, help="proposal network: top-down and head channels (default 48)")
    tr.add_argument("--channels", type=int, nargs=5, default=[16, 32, 64, 96, 128], metavar="C",
                    help="proposal network: stem and pyramid channels at strides 2-32 (default 16 32 64 96 128)")
    tr.add_argument("--max-minutes", type=float, default=0.0,
                    help="stop each network's training after this many minutes (wall; default 0: no limit)")
    tr.add_argument("--validation", nargs="+", default=VALIDATION,
                    help="name patterns of the validation shards (default: seeds ending in 9)")
    tr.add_argument("--oversample", nargs="+", default=[], metavar="PATTERN=N",
                    help="use the training shards matching PATTERN N times (e.g. 'table1-*=2')")
    qu = sub.add_parser("quantize", help="the 8-bit copy of a second stage, calibrated on shards")
    qu.add_argument("shards", type=Path)
    qu.add_argument("--model", type=Path, required=True, help="the second stage to quantize (e.g. OUT/circle_refine.onnx)")
    qu.add_argument("-o", "--out", type=Path, default=None,
                    help="the quantized network (default: <model stem>_int8.onnx beside the model) and its report (.json)")
    qu.add_argument("--samples", type=int, default=2048, help="calibration windows (default 2048)")
    qu.add_argument("--seed", type=int, default=0)
    qu.add_argument("--validation", nargs="+", default=VALIDATION,
                    help="name patterns of the validation shards (default: seeds ending in 9)")
    lb = sub.add_parser("label", help="a shard from labelled frames (JSON)")
    lb.add_argument("labels", type=Path)
    lb.add_argument("shard", type=Path)
    lb.add_argument("--input-size", default=None, metavar="WxH",
                    help="the frames' size in the shard (default: the shipped proposal network's input)")
    args = ap.parse_args(argv)
    try:
        if args.command == "label":
            from agents.perception.training.data import shard_from_labels, write_shard

            if args.input_size is None:
                from agents.perception.learned import MODEL_DIR, model_input_size

                size = model_input_size(MODEL_DIR / "circles.onnx")
            else:
                size = _size(args.input_size)
            arrays = shard_from_labels(args.labels, input_size=size)
            write_shard(args.shard, arrays)
            print(f"{args.shard}: {len(arrays['images'])} frames, {len(arrays['circles'])} circles")
            return 0
        if args.command == "quantize":
            return _quantize(args)
        if min(args.steps, args.refine_steps, args.batch, args.eval_every, args.width, *args.channels) < 1 or args.lr <= 0:
            raise InputError("--steps, --refine-steps, --batch, --eval-every, --width, --channels and --lr must be positive",
                             field="options")
        if args.workers < 0 or args.max_minutes < 0:
            raise InputError("--workers and --max-minutes must not be negative", field="options")
        train_files, val_files = _split(args.shards, args.validation)
        os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
        try:
            from agents.perception.training.train import TrainConfig, train
        except ImportError as exc:
            raise InputError(f"training needs PyTorch (pip install 'decentral[train]'): {exc}", field="torch") from None
        from agents.perception.training.data import load_shards

        for item in args.oversample:
            pattern, _, times = item.rpartition("=")
            if not pattern or not times.isdigit() or int(times) < 1:
                raise InputError(f"expected PATTERN=N, got {item!r}", field="--oversample")
            train_files += [f for f in train_files if fnmatch.fnmatch(f.name, pattern)] * (int(times) - 1)
        data, val = load_shards(train_files), load_shards(val_files)
        extra = {"train_shards": [f.name for f in train_files], "validation_shards": [f.name for f in val_files]}
        print(f"{len(data.images)} training frames ({len(train_files)} shards), {len(val.images)} validation frames",
              flush=True)
        for network, steps in (("detector", args.steps), ("refine", args.refine_steps)):
            if args.network in (network, "both"):
                cfg = TrainConfig(steps=steps, batch=args.batch if network == "detector" else 4 * args.batch,
                                  lr=args.lr, seed=args.seed, eval_every=args.eval_every, warmup=args.warmup,
                                  device=args.device, workers=args.workers, width=args.width,
                                  channels=tuple(args.channels), max_seconds=60.0 * args.max_minutes)
                init = None
                if args.init is not None:
                    stem = "circles" if network == "detector" else "circle_refine"
                    init = args.init / f"{stem}.pt"
                    if not init.is_file():
                        init = args.init / f"{stem}.onnx"
                    if not init.is_file():
                        raise InputError(f"no earlier weights to start from ({stem}.pt or {stem}.onnx)", source=str(args.init))
                train(network, data, val, args.out, cfg, extra=extra, progress=lambda s: print(s, flush=True), init=init)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
