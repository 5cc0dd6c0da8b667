"""Training the learned detector's networks on the CPU or a GPU, and their export to ONNX (PyTorch).

:func:`train` runs one network (``"detector"``: :class:`~agents.perception.training.model.CircleNet`,
``"refine"``: :class:`~agents.perception.training.model.RefineNet`) for a fixed number of steps from
one seed: the same seed, shards and settings give the same weights up to floating-point noise on the
CPU (one thread; the batches come from the seed and each step's augmentations from the seed and the
step, so ``workers`` processes preparing batches change nothing). On a GPU (``device="cuda"``, or
``"auto"`` where one is found) the same batches are used; cuDNN's kernels make its runs repeat only
approximately. Every ``eval_every`` steps the validation loss is computed and the best weights so far
are exported to ONNX, so a run stopped early still leaves its best model. The loss curves go to
``<name>_training.json`` and ``.png`` beside it.
"""

from __future__ import annotations

import collections
import copy
import json
import math
import multiprocessing
import os
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch
from torch.nn import functional as F

from agents.perception.training.data import Shards, detector_batch, refine_batch
from agents.perception.training.model import CircleNet, RefineNet
from decentral.errors import InputError

__all__ = ["TrainConfig", "circlenet_from_onnx", "export_onnx", "focal_loss", "load_onnx_weights", "resolve_device",
           "train"]


@dataclass(frozen=True)
class TrainConfig:
    """Steps, batch, learning rate (AdamW, linear warm-up then cosine decay), seed, evaluation period.

    ``device``: ``"auto"`` (a CUDA GPU where torch finds one, else the CPU), ``"cpu"`` or ``"cuda"``;
    ``workers``: processes preparing the batches (0: the training process itself); ``width`` and
    ``channels``: the proposal network's (:class:`~agents.perception.training.model.CircleNet`);
    ``max_seconds`` > 0: stop (after a last validation) once training has run this long (wall).
    """

    steps: int = 3000
    batch: int = 24
    lr: float = 2e-3
    weight_decay: float = 1e-4
    warmup: int = 100
    seed: int = 0
    eval_every: int = 100
    threads: int = 1
    device: str = "auto"
    workers: int = 0
    width: int = 48
    channels: tuple[int, ...] = (16, 32, 64, 96, 128)
    max_seconds: float = 0.0


def resolve_device(device: str) -> torch.device:
    """``"auto"`` -> CUDA where available, else the CPU; ``"cuda"`` without a GPU is an InputError."""
    if device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if device == "cuda" and not torch.cuda.is_available():
        raise InputError("no CUDA GPU is available to torch (use --device cpu or auto)", field="--device")
    if device not in ("cpu", "cuda"):
        raise InputError(f"unknown device {device!r} (auto, cpu or cuda)", field="--device")
    return torch.device(device)


def focal_loss(logit: torch.Tensor, heat: torch.Tensor, weight: torch.Tensor, pos: torch.Tensor) -> torch.Tensor:
    """CenterNet's penalty-reduced focal loss (Zhou et al. 2019 eq. 1), per positive."""
    logp, log1mp = F.logsigmoid(logit), F.logsigmoid(-logit)
    p = torch.sigmoid(logit)
    pos_loss = -(log1mp.exp() ** 2) * logp * pos
    neg_loss = -((1 - heat) ** 4) * p ** 2 * log1mp * (1 - pos) * weight
    return (pos_loss.sum() + neg_loss.sum()) / pos.sum().clamp(min=1.0)


def _tensors(batch, device: torch.device):
    return (torch.from_numpy(a).to(device, non_blocking=True) for a in batch)


def _detector_loss(net: CircleNet, batch, device: torch.device = torch.device("cpu")) -> tuple[torch.Tensor, dict]:
    x, heat, weight, reg = _tensors(batch, device)
    out = net.logits(x)
    pos = reg[:, 3:4]
    n = pos.sum().clamp(min=1.0)
    hm = focal_loss(out[:, :1], heat, weight, pos)
    rad = (torch.abs(out[:, 1:2] - reg[:, 0:1]) * pos).sum() / n
    off = (torch.abs(out[:, 2:4] - reg[:, 1:3]) * pos).sum() / n
    return hm + rad + off, {"heatmap": hm.item(), "log_radius": rad.item(), "offset": off.item()}


def _refine_loss(net: RefineNet, batch, device: torch.device = torch.device("cpu")) -> tuple[torch.Tensor, dict]:
    x, y = _tensors(batch, device)
    err = torch.abs(net(x) - y)
    centre, radius = err[:, :2].mean(), err[:, 2].mean()
    return centre + radius, {"centre": centre.item(), "log_radius": radius.item()}


def export_onnx(net: torch.nn.Module, path: str | os.PathLike, shape: tuple[int, ...], output: str) -> None:
    """Export ``net`` (eval mode, a CPU copy) with one input ``image`` of ``shape`` and one output named ``output``.

    A network with a ``config`` dict (:class:`~agents.perception.training.model.CircleNet`) keeps it in
    the file's metadata (``circlenet``), so that :func:`circlenet_from_onnx` can rebuild it.
    """
    net = copy.deepcopy(net).cpu().eval()
    path = Path(path)
    tmp = path.with_name(f".{path.name}.part")
    with torch.no_grad():
        torch.onnx.export(net, torch.zeros(shape), str(tmp), input_names=["image"], output_names=[output],
                          opset_version=17, do_constant_folding=True, dynamo=False,
                          dynamic_axes={"image": {0: "batch"}, output: {0: "batch"}} if output == "circle" else None)
    config = getattr(net, "config", None)
    if config:
        import onnx

        model = onnx.load(str(tmp))
        entry = model.metadata_props.add()
        entry.key, entry.value = "circlenet", json.dumps(config)
        onnx.save(model, str(tmp))
    os.replace(tmp, path)


def circlenet_from_onnx(path: str | os.PathLike) -> CircleNet:
    """A fresh :class:`CircleNet` of the shape of the exported network at ``path`` (its ``circlenet``
    metadata; the first release's shape where there is none)."""
    import onnx

    model = onnx.load(str(path), load_external_data=False)
    meta = {p.key: p.value for p in model.metadata_props}
    if "circlenet" not in meta:
        return CircleNet()
    config = json.loads(meta["circlenet"])
    return CircleNet(int(config["width"]), tuple(int(c) for c in config["channels"]))


def load_onnx_weights(net: torch.nn.Module, path: str | os.PathLike, batches) -> float:
    """Load an exported network's weights back into ``net`` (to fine-tune a shipped model).

    The export folds each batch normalisation into the convolution before it (``W' = W g / s``,
    ``b' = beta - g m / s``); the convolutions are matched in execution order by shape. Each
    normalisation then gets the mean ``m`` and variance ``v`` of its folded convolution's output
    over ``batches`` (inputs, (B, C, H, W)) as running statistics, ``gamma = sqrt(v + eps)`` and
    ``beta = m + b'``: in evaluation mode the network computes exactly the exported function, and in
    training mode (batch statistics) nearly so. Returns the largest absolute difference between the
    network's and onnxruntime's outputs on the first batch.
    """
    import onnx
    import onnxruntime as ort
    from onnx import numpy_helper

    model = onnx.load(str(path))
    inits = {i.name: numpy_helper.to_array(i) for i in model.graph.initializer}
    convs = [n for n in model.graph.node if n.op_type in ("Conv", "Gemm")]
    order: list[torch.nn.Module] = []
    hooks = [m.register_forward_hook(lambda m, i, o: order.append(m)) for m in net.modules()
             if isinstance(m, (torch.nn.Conv2d, torch.nn.Linear))]
    net.eval()
    x0 = torch.from_numpy(batches[0])
    with torch.no_grad():
        net(x0[:1])
    for h in hooks:
        h.remove()
    if len(order) != len(convs):
        raise ValueError(f"{path}: {len(convs)} convolutions, the network has {len(order)}")
    bn_after = {}
    for seq in net.modules():
        kids = list(seq.children()) if isinstance(seq, torch.nn.Sequential) else []
        for a, b in zip(kids, kids[1:]):
            if isinstance(b, torch.nn.BatchNorm2d):
                bn_after[a] = b
    bias = {}
    with torch.no_grad():
        for mod, node in zip(order, convs):
            w = torch.from_numpy(inits[node.input[1]].copy())
            if tuple(w.shape) != tuple(mod.weight.shape):
                raise ValueError(f"{path}: weights of shape {tuple(w.shape)} where the network has {tuple(mod.weight.shape)}")
            mod.weight.copy_(w)
            b = torch.from_numpy(inits[node.input[2]].copy()) if len(node.input) > 2 else torch.zeros(w.shape[0])
            if mod in bn_after:
                bn = bn_after[mod]
                bias[bn] = b
                bn.running_mean.zero_()
                bn.running_var.fill_(1.0 - bn.eps)
                bn.weight.fill_(1.0)
                bn.bias.copy_(b)
            else:
                mod.bias.copy_(b)
    sums: dict = {bn: [0.0, 0.0, 0] for bn in bias}

    def record(bn, inp, _out):
        x = inp[0].double()
        s = sums[bn]
        s[0] = s[0] + x.sum(dim=(0, 2, 3))
        s[1] = s[1] + (x * x).sum(dim=(0, 2, 3))
        s[2] += x.numel() // x.shape[1]

    hooks = [bn.register_forward_hook(record) for bn in bias]
    with torch.no_grad():
        for xb in batches:
            net(torch.from_numpy(xb))
    for h in hooks:
        h.remove()
    with torch.no_grad():
        for bn, (s1, s2, n) in sums.items():
            m = s1 / n
            v = (s2 / n - m * m).clamp(min=1e-6)
            bn.running_mean.copy_(m.float())
            bn.running_var.copy_(v.float())
            bn.weight.copy_(torch.sqrt(v + bn.eps).float())
            bn.bias.copy_((m + bias[bn].double()).float())
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    name = sess.get_inputs()[0].name
    k = min(4, len(batches[0]))
    ref = np.concatenate([sess.run(None, {name: batches[0][i:i + 1]})[0] for i in range(k)])
    with torch.no_grad():
        got = net(x0[:k]).numpy()
    return float(np.abs(got - ref).max())


def _plot(log: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.5))
    tr = np.asarray(log["train"])
    if len(tr):
        k = max(1, len(tr) // 100)
        smooth = np.convolve(tr[:, 1], np.ones(k) / k, mode="valid")
        ax.plot(tr[k - 1:, 0], smooth, label=f"training (mean of {k} steps)")
    va = np.asarray([(e["step"], e["loss"]) for e in log["validation"]])
    if len(va):
        ax.plot(va[:, 0], va[:, 1], "o-", ms=3, label="validation")
    ax.set_xlabel("step")
    ax.set_ylabel("loss")
    ax.set_yscale("log")
    ax.set_title(f"{log['network']}: loss", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


#: the training data of the batch-preparing worker processes (inherited by fork, never pickled), and the
#: shared buffers ("slots") they write the proposal network's input batches into
_WORKER_DATA: dict = {}


def _make_batch(job) -> tuple:
    """One step's batch: ``job`` = (network, seed, step, indices, slot); augmentations from (seed, step).

    ``step`` is the step number (>= 1), or a pair (0, k) for the k-th batch drawn before training.
    ``slot`` (a worker's job; None otherwise): the batch's inputs go to that shared buffer and the
    slot's number is returned in their place (a 32-frame batch is 42 MB: passed through a pipe, its
    bytes, not the augmentation, set the pace of training on a GPU).
    """
    network, seed, step, idx, slot = job
    data = _WORKER_DATA["data"]
    rng = np.random.default_rng([seed, *np.atleast_1d(step)])
    batch = detector_batch(data, idx, rng) if network == "detector" else refine_batch(data, idx, rng)
    if slot is None:
        return batch
    _WORKER_DATA["slots"][slot][:len(batch[0])] = batch[0]
    return (slot, *batch[1:])


def _shared_slots(count: int, shape: tuple[int, ...]) -> np.ndarray:
    """``count`` float32 buffers of ``shape`` in memory that forked processes share: (count, *shape)."""
    raw = multiprocessing.get_context("fork").RawArray("f", int(count * np.prod(shape)))
    return np.frombuffer(raw, np.float32).reshape(count, *shape)


def _batches(pool, jobs, ahead: int):
    """The batches of ``jobs`` in order: made here (``pool`` None) or by ``pool``, at most ``ahead`` in flight.

    With a pool and slots (:func:`_shared_slots`, at least ``ahead + 1``), a job's inputs come back
    through the slot of its number: a slot is written again only after its batch was handed on and
    the next one asked for, and the batch handed on is a copy.
    """
    if pool is None:
        for job in jobs:
            yield _make_batch((*job, None))
        return
    slots = _WORKER_DATA.get("slots")
    pending: collections.deque = collections.deque()

    def result(handle):
        out = handle.get()
        if slots is None:
            return out
        return (slots[out[0]][:len(out[1])].copy(), *out[1:])

    for k, job in enumerate(jobs):
        slot = k % len(slots) if slots is not None else None
        pending.append(pool.apply_async(_make_batch, ((*job, slot),)))
        if len(pending) >= ahead:
            yield result(pending.popleft())
    while pending:
        yield result(pending.popleft())


def train(network: str, data: Shards, val: Shards, out: str | os.PathLike, config: TrainConfig = TrainConfig(),
          *, name: str | None = None, progress=print, extra: dict | None = None, init: str | os.PathLike | None = None) -> dict:
    """Train ``network`` ("detector" or "refine") and write ``out/<name>.onnx`` and ``out/<name>_training.{json,png}``.

    ``init`` (a ``.pt`` state dict written by an earlier run, or an exported ``.onnx`` network such
    as the shipped one: :func:`load_onnx_weights`) starts from those weights (fine-tuning, e.g. on a
    user's own labelled frames). Returns the training log (also the JSON file):
    configuration, per-step training loss, validation losses, best step, wall and CPU seconds
    (CPU: this process's; with ``workers`` the batch preparation's is not counted) and the device.
    """
    if network not in ("detector", "refine"):
        raise ValueError(f"unknown network {network!r} (detector or refine)")
    device = resolve_device(config.device)
    name = name or ("circles" if network == "detector" else "circle_refine")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(config.threads)
    torch.manual_seed(config.seed)
    rng = np.random.default_rng(config.seed)
    val_rng = np.random.default_rng(12345)
    if network == "detector":
        h, w = data.images.shape[1:3]
        if h % 32 or w % 32:
            raise InputError(f"the frames are {w} x {h}: the proposal network needs multiples of 32 (e.g. 384 x 288)",
                             field="shards")
        if init is not None and str(init).endswith(".onnx"):
            net = circlenet_from_onnx(init)
            arch = getattr(net, "config", None) or {}
            if arch:  # the shape comes from the file: the log records it, not the options' defaults
                config = replace(config, width=int(arch["width"]), channels=tuple(int(c) for c in arch["channels"]))
        else:
            net = CircleNet(config.width, tuple(config.channels))
        loss_fn = _detector_loss
        n_train, items = len(data.images), np.arange(len(data.images))
        val_idx = np.arange(min(len(val.images), 240))
        val_batches = [detector_batch(val, val_idx[i:i + config.batch], None) for i in range(0, len(val_idx), config.batch)]
        shape, output = (1, 3, h, w), "heads"
    else:
        net, loss_fn = RefineNet(), _refine_loss
        items = np.nonzero(data.circles[:, 4] >= 0.3)[0]
        n_train = len(items)
        v_usable = np.nonzero(val.circles[:, 4] >= 0.3)[0][:1024]
        val_batches = [refine_batch(val, v_usable[i:i + 128], val_rng) for i in range(0, len(v_usable), 128)]
        shape, output = (1, 3, 32, 32), "circle"
    if init is not None and str(init).endswith(".onnx"):
        _WORKER_DATA["data"] = data
        stats = [_make_batch((network, config.seed, (0, k), items[rng.permutation(n_train)[:config.batch]], None))[0]
                 for k in range(8)]
        diff = load_onnx_weights(net, init, stats)
        if progress:
            progress(f"{network}: weights of {init} (largest difference from onnxruntime {diff:.2g})")
    elif init is not None:
        try:
            net.load_state_dict(torch.load(init, weights_only=True, map_location="cpu"))
        except RuntimeError:  # another network's shape
            raise InputError("the weights do not fit the network: give the --width and --channels they were "
                             "trained with", source=str(init)) from None
    _WORKER_DATA["data"] = data
    pool = None  # forked before CUDA starts; the workers only run numpy and OpenCV
    ahead = 2 * config.workers + 2
    try:  # (the workers and shared slots are let go on every exit: a failing fork, CUDA or optimizer too)
        if config.workers > 0 and "fork" in multiprocessing.get_all_start_methods():
            if network == "detector":
                _WORKER_DATA["slots"] = _shared_slots(ahead + 1, (config.batch, 3, *data.images.shape[1:3]))
            pool = multiprocessing.get_context("fork").Pool(config.workers)
        net.to(device)
        if device.type == "cuda":
            torch.backends.cudnn.benchmark = True
        opt = torch.optim.AdamW(net.parameters(), lr=config.lr, weight_decay=config.weight_decay)
        log = {"network": network, "config": asdict(config), "device": str(device),
               "device_name": torch.cuda.get_device_name(device) if device.type == "cuda" else "cpu",
               "architecture": getattr(net, "config", None),
               "init": None if init is None else str(init), "train_items": int(n_train),
               "validation_items": int(sum(len(b[0]) for b in val_batches)), "train": [], "validation": [],
               "parts": [], **(extra or {})}

        def jobs():
            order, pos = rng.permutation(n_train), 0
            for step in range(1, config.steps + 1):
                if pos + config.batch > n_train:
                    order, pos = rng.permutation(n_train), 0
                yield network, config.seed, step, items[order[pos:pos + config.batch]]
                pos += config.batch

        _loop(net, opt, loss_fn, _batches(pool, jobs(), ahead), val_batches, config, device, log,
              out, name, shape, output, progress)
    finally:
        if pool is not None:
            pool.terminate()
            pool.join()
        _WORKER_DATA.pop("slots", None)
    return log


def _loop(net, opt, loss_fn, batches, val_batches, config: TrainConfig, device, log: dict, out: Path, name: str,
          shape, output: str, progress) -> None:
    """The optimisation steps, validation, best-model export and logs of :func:`train`.

    A fine-tune (``log["init"]`` set) is validated before its first step too (step 0): the starting
    network's loss on the same validation set, kept (and exported) unless a later step does better.
    """
    best = math.inf
    wall0, cpu0 = time.perf_counter(), time.process_time()

    def validate(step: int) -> None:
        nonlocal best
        net.eval()
        with torch.no_grad():
            vals = [loss_fn(net, b, device) for b in val_batches]
        v = float(np.mean([float(a) for a, _ in vals]))
        vparts = {k: float(np.mean([p[k] for _, p in vals])) for k in vals[0][1]}
        entry = {"step": step, "loss": v, **vparts, "wall_s": time.perf_counter() - wall0,
                 "cpu_s": time.process_time() - cpu0}
        log["validation"].append(entry)
        if v < best:
            best = v
            log["best_step"] = step
            torch.save({k: t.detach().cpu() for k, t in net.state_dict().items()}, out / f"{name}.pt")
            export_onnx(net, out / f"{name}.onnx", shape, output)
        log["wall_seconds"] = time.perf_counter() - wall0
        log["cpu_seconds"] = time.process_time() - cpu0
        with open(out / f"{name}_training.json", "w") as fh:
            json.dump(log, fh)
        _plot(log, out / f"{name}_training.png")
        if progress:
            recent = [t for _, t in log["train"][-config.eval_every:]]
            trained = f"train {np.mean(recent):.4f} " if recent else "(the starting network) "
            progress(f"{log['network']} step {step}/{config.steps}: {trained}validation {v:.4f} {vparts} "
                     f"({entry['wall_s']:.0f} s wall, {entry['cpu_s']:.0f} s CPU)")

    if log.get("init") is not None:
        validate(0)
    for step, batch in enumerate(batches, start=1):
        lr = config.lr * min(1.0, step / config.warmup) * 0.5 * (1 + math.cos(math.pi * step / config.steps))
        for g in opt.param_groups:
            g["lr"] = lr
        net.train()
        loss, parts = loss_fn(net, batch, device)
        opt.zero_grad()
        loss.backward()
        opt.step()
        log["train"].append((step, loss.item()))
        log["parts"].append(parts)
        stop = 0 < config.max_seconds < time.perf_counter() - wall0
        if stop:
            log["stopped_at_step"] = step  # the time limit: the schedule did not run to its end
        if step % config.eval_every == 0 or step == config.steps or stop:
            validate(step)
        if stop:
            break
