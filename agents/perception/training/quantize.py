"""An 8-bit copy of the second stage: the same network, three times as fast on one core.

The second stage (``circle_refine.onnx``) runs once per circle and pass, 20-30 times a frame; at
about 0.45 ms per window in 32-bit floats it was half of the learned detector's time. Static
post-training quantization (onnxruntime's ``quantize_static``) stores its weights as 8-bit integers
(per output channel) and runs its convolutions on 8-bit activations whose ranges are calibrated on
the network's own training inputs (:func:`agents.perception.training.data.refine_batch`: true
circles' crops around randomly moved and scaled proposals, as in training).

- **Format**: operator-oriented (``QLinearConv``), which both backends load (OpenCV's ``dnn`` does not
  load the tensor-oriented QDQ form); activations unsigned, weights signed.
- **7-bit weights** (``reduce_range``): x86 CPUs without VNNI multiply 8-bit pairs into 16-bit sums
  that can saturate with full-range weights; with 7 bits they cannot, so the copy gives the same
  corrections on every x86 CPU, not only on the one it was made on.
- **Checked**: the corrections of both copies on the validation windows; the report gives the largest
  and the 99th-percentile difference (in radii) so that a poor calibration is seen before shipping.

Needs ``onnx`` (the ``train`` extra; PyTorch is not needed).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from agents.perception.learned import OnnxNet
from agents.perception.training.data import Shards, refine_batch
from decentral.errors import InputError

__all__ = ["quantize_refine", "refine_agreement"]


def _windows(data: Shards, n: int, seed: int) -> np.ndarray:
    """``n`` second-stage inputs (n, 3, 32, 32) drawn from ``data``'s circles with ``refine_batch``."""
    if not len(data.crops):
        raise InputError("the shards hold no circles", field="shards")
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, len(data.crops), n)
    return refine_batch(data, idx, rng)[0]


def _outputs(path: str | os.PathLike, x: np.ndarray) -> np.ndarray:
    """The network at ``path`` (onnxruntime, one thread) on windows ``x``, 64 at a time: (n, 3) float64."""
    net = OnnxNet(path, "onnxruntime", 1)
    return np.concatenate([net.run(x[i:i + 64]) for i in range(0, len(x), 64)]).astype(np.float64)


def refine_agreement(model: str | os.PathLike, quantized: str | os.PathLike, x: np.ndarray) -> dict:
    """How far the quantized second stage's outputs lie from the float one's on windows ``x`` (n, 3, 32, 32).

    Returns the largest, 99th-percentile and median absolute difference per output (du / r, dv / r,
    log radius ratio), in radii, and the number of windows.
    """
    d = np.abs(_outputs(model, x) - _outputs(quantized, x))
    return {"windows": int(len(x)), "max": d.max(axis=0).round(5).tolist(),
            "p99": np.percentile(d, 99, axis=0).round(5).tolist(), "median": np.median(d, axis=0).round(5).tolist()}


def quantize_refine(model: str | os.PathLike, data: Shards, val: Shards, out: str | os.PathLike, *,
                    samples: int = 2048, seed: int = 0) -> dict:
    """Write the 8-bit copy of second stage ``model`` to ``out`` and a report beside it (``.json``).

    ``samples`` windows of the training shards ``data`` calibrate the activations' ranges (drawn
    from ``seed``; the same seed and shards give the same file); as many windows of ``val`` check
    the copy (:func:`refine_agreement`). The file is written under a temporary name and moved into
    place, so a failure leaves nothing half-written. Returns the report.
    """
    try:
        from onnxruntime.quantization import CalibrationDataReader, QuantFormat, QuantType, quantize_static
        from onnxruntime.quantization.shape_inference import quant_pre_process
    except ImportError as exc:
        raise InputError(f"quantizing needs the onnx package (pip install 'decentral[train]'): {exc}",
                         field="onnx") from None
    model, out = Path(model), Path(out)
    if samples < 1:
        raise InputError("must be positive", field="--samples")
    name = OnnxNet(model, "onnxruntime", 1).input  # (a missing file or one that is no network: an InputError naming it)
    calibration = _windows(data, samples, seed)

    class _Reader(CalibrationDataReader):
        def __init__(self):
            self._batches = iter([{name: calibration[i:i + 64]} for i in range(0, len(calibration), 64)])

        def get_next(self):
            return next(self._batches, None)

    out.parent.mkdir(parents=True, exist_ok=True)
    pre, tmp = out.with_suffix(".pre.tmp"), out.with_suffix(".onnx.tmp")
    try:
        try:
            quant_pre_process(str(model), str(pre), skip_symbolic_shape=True)
            quantize_static(str(pre), str(tmp), _Reader(), quant_format=QuantFormat.QOperator,
                            activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8,
                            per_channel=True, reduce_range=True)
        except Exception as exc:  # onnx and onnxruntime raise their own types for a file that is no such network
            raise InputError(f"cannot quantize this model ({exc.__class__.__name__}: {str(exc).splitlines()[0][:200]})",
                             source=str(model)) from None
        report = {"model": model.name, "quantized": out.name, "calibration_windows": int(samples), "seed": int(seed),
                  "format": "QOperator, uint8 activations, int8 per-channel 7-bit weights (reduce_range)",
                  "validation": refine_agreement(model, tmp, _windows(val, samples, seed + 1))}
        os.replace(tmp, out)
    finally:
        for p in (pre, tmp):
            p.unlink(missing_ok=True)
    report_tmp = out.with_suffix(".json.tmp")
    report_tmp.write_text(json.dumps(report, indent=1) + "\n")
    os.replace(report_tmp, out.with_suffix(".json"))
    return report
