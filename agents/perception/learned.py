"""The learned circle detector: a small network's proposals, each polished by a second network.

Liu et al. 2024 §III-A detect nodes with a network whose head outputs bounding circles. This is a
CenterNet-style (Zhou et al. 2019) version small enough for one CPU core, trained on rendered frames
(:mod:`agents.perception.training`; the model card ``agents/perception/models/circles.md`` gives its
data, training and scores):

1. *Proposals* (``circles.onnx``): the frame resized to the network's input size, read from the
   ONNX file's input shape (the shipped network: 384 x 288; padded to its aspect ratio first if
   needed), gives, on the grid of stride 4, a centre heatmap, the log radius and the centre's
   sub-cell offset; each 3 x 3 local maximum of the heatmap of at least ``threshold`` is a circle.
2. *Second stage* (``circle_refine.onnx``, or with onnxruntime its 8-bit copy
   ``circle_refine_int8.onnx``: :mod:`agents.perception.training.quantize`), ``refine_passes`` times: a window 2.5 radii wide around
   each circle, at full resolution, resampled to 32 x 32 (:mod:`agents.perception.crops`), gives the
   true circle relative to it. It was trained on partly hidden spheres too, so such a sphere's radius
   comes from its visible rim.
3. A circle whose last pass still moved it by more than ``converge`` (5 %) of its radius has not
   settled on a rim and is dropped: on the validation scenes this removed most false and double
   circles (0.19-0.35 false circles per sphere to 0-0.04) for 0-0.1 of the recall.
4. Circles whose centres lie within half the larger radius of a better one are dropped.

The networks run with onnxruntime (a dependency; the faster here) or OpenCV's ``dnn`` module
(``backend="opencv"``, also the fallback where onnxruntime is missing); one thread by default. Both files ship with the package: nothing
is downloaded.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from agents.perception.crops import CROP_SIZE, crop_circle, refine_input
from agents.perception.heap import keep_freed_memory
from agents.perception.onnx_shape import onnx_input_shape
from agents.perception.types import Circle
from decentral.errors import InputError

__all__ = ["MODEL_DIR", "LearnedCircleDetector", "LearnedConfig", "OnnxNet", "decode", "model_input_size",
           "quantized_path", "resolve_backend", "second_stage_path"]

#: folder of the shipped networks (package data)
MODEL_DIR = Path(__file__).resolve().parent / "models"


@dataclass(frozen=True)
class LearnedConfig:
    """Parameters of :class:`LearnedCircleDetector`.

    Attributes
    ----------
    model, refine_model : path
        The proposal network and the second stage (ONNX); ``refine_model`` None: proposals only.
    threshold : float
        Smallest heatmap peak kept as a circle (0-1).
    refine_passes : int
        Passes of the second stage (each starts from the previous pass's circle).
    min_radius, max_radius : float
        Circles outside this range (px) are dropped.
    backend : str
        ``"onnxruntime"``, ``"opencv"`` (``cv2.dnn``) or ``"auto"`` (onnxruntime where it is
        installed, else OpenCV): both give the same circles (within 0.01 px); onnxruntime ran the
        second stage 1.7 times as fast (3.2 against 5.5 ms for 7 crops) and the proposals 1.8 times.
    threads : int
        Threads of the onnxruntime backend (OpenCV's are set process-wide by ``cv2.setNumThreads``).
    quantized : bool
        With onnxruntime, run the second stage's 8-bit copy ``<refine_model stem>_int8.onnx`` where one
        lies beside it (``python -m agents.perception.training quantize``; the shipped one has it): three
        times as fast (0.15 against 0.45 ms a window), its circles within 0.2 px (median) and 2 % of the
        radius of the float network's. OpenCV's ``dnn`` always runs the float network (its 8-bit
        kernels moved circles by several pixels).
    converge : float
        A circle whose last second-stage pass still moved its centre or changed its radius by more
        than this fraction of its radius is dropped (it has not settled on a rim); 1: keep all.
    overlap : float
        A circle whose centre lies within ``overlap`` times the larger radius of a better circle is dropped.
    """

    model: str | os.PathLike = MODEL_DIR / "circles.onnx"
    refine_model: str | os.PathLike | None = MODEL_DIR / "circle_refine.onnx"
    threshold: float = 0.4
    refine_passes: int = 4
    min_radius: float = 8.0
    max_radius: float = 160.0
    backend: str = "auto"
    threads: int = 1
    quantized: bool = True
    converge: float = 0.05
    overlap: float = 0.5


def model_input_size(path: str | os.PathLike) -> tuple[int, int]:
    """(width, height) of the frames a proposal network takes: its ONNX input shape (N, 3, H, W).

    A file whose input is not a fixed-size colour frame with sides a multiple of the stride (4) is an
    :class:`~decentral.errors.InputError` naming it.
    """
    shape = onnx_input_shape(path)
    if len(shape) != 4 or shape[1] != 3 or not all(isinstance(d, int) and d >= 4 and d % 4 == 0 for d in shape[2:]):
        raise InputError(f"the proposal network's input is {shape}, not (N, 3, H, W) with H and W multiples of 4",
                         source=str(path))
    return int(shape[3]), int(shape[2])


def resolve_backend(backend: str) -> str:
    """``"auto"`` -> ``"onnxruntime"`` where it is installed, else ``"opencv"``; other names unchanged."""
    if backend != "auto":
        return backend
    try:
        import onnxruntime  # noqa: F401
    except ImportError:
        return "opencv"
    return "onnxruntime"


def quantized_path(model: str | os.PathLike) -> Path:
    """Where the 8-bit copy of second stage ``model`` lies: ``<stem>_int8.onnx`` beside it."""
    model = Path(model)
    return model.with_name(f"{model.stem}_int8.onnx")


def second_stage_path(config: LearnedConfig, backend: str) -> Path | None:
    """The second-stage file ``backend`` runs: the 8-bit copy beside ``refine_model`` (see
    :attr:`LearnedConfig.quantized`) with onnxruntime where it exists, else ``refine_model`` itself."""
    if config.refine_model is None:
        return None
    path, copy = Path(config.refine_model), quantized_path(config.refine_model)
    if config.quantized and resolve_backend(backend) == "onnxruntime" and copy.is_file():
        return copy
    return path


class OnnxNet:
    """One ONNX network behind either backend: ``run(x)`` for an (N, C, H, W) float32 batch."""

    def __init__(self, path, backend: str, threads: int):
        path = Path(path)
        backend = resolve_backend(backend)
        if not path.is_file():
            raise InputError("model file not found", source=str(path))
        self.backend = backend
        if backend == "onnxruntime":
            try:
                import onnxruntime as ort
            except ImportError:
                raise InputError("the onnxruntime backend needs the onnxruntime package", field="backend") from None
            so = ort.SessionOptions()
            so.intra_op_num_threads = threads
            so.inter_op_num_threads = 1
            try:
                self.session = ort.InferenceSession(str(path), so, providers=["CPUExecutionProvider"])
            except Exception as exc:  # onnxruntime raises its own exception types
                raise InputError(f"cannot load the ONNX model ({exc})", source=str(path)) from None
            self.input = self.session.get_inputs()[0].name
        elif backend == "opencv":
            try:
                self.net = cv2.dnn.readNetFromONNX(str(path))
            except cv2.error as err:
                raise InputError(f"cannot load the ONNX model ({str(err).strip().splitlines()[-1]})",
                                 source=str(path)) from None
            if self.net.empty():
                raise InputError("cannot load the ONNX model", source=str(path))
        else:
            raise InputError(f"unknown backend {backend!r} (opencv or onnxruntime)", field="backend")

    def run(self, x: np.ndarray) -> np.ndarray:
        if self.backend == "onnxruntime":
            return self.session.run(None, {self.input: x})[0]
        self.net.setInput(x)
        return np.asarray(self.net.forward())


def _to_input(images: np.ndarray) -> np.ndarray:
    """(N, H, W, 3) uint8 BGR -> (N, 3, H, W) float32 in [-0.5, 0.5] (as in training)."""
    return np.asarray(images, np.float32).transpose(0, 3, 1, 2) * np.float32(1 / 255.0) - np.float32(0.5)


def decode(out: np.ndarray, scale: float, threshold: float, stride: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Circles (n, 3) in image pixels and their peaks (n,) from the proposal network's output.

    ``out`` (4, h, w): heatmap, log radius (input pixels), offset x, y (cells); ``scale``: image
    pixels per input pixel. A circle is each 3 x 3 local maximum of the heatmap of at least
    ``threshold``. The mapping is the inverse of the training targets'
    (:func:`agents.perception.training.data.detector_targets`, input pixel = image pixel / scale).
    """
    heat = np.ascontiguousarray(out[0], np.float32)
    peaks = (heat >= threshold) & (heat >= cv2.dilate(heat, np.ones((3, 3), np.uint8)))
    ys, xs = np.nonzero(peaks)
    u = ((xs + out[2, ys, xs] + 0.5) * stride - 0.5) * scale
    v = ((ys + out[3, ys, xs] + 0.5) * stride - 0.5) * scale
    r = np.exp(out[1, ys, xs]) * scale
    circles = np.column_stack([u, v, r]).astype(np.float64)
    keep = np.isfinite(circles).all(axis=1)
    return circles[keep], heat[ys, xs][keep].astype(np.float64)


class LearnedCircleDetector:
    """A :class:`~agents.perception.types.CircleDetector` running the shipped (or a user's) networks."""

    stride = 4
    #: a circle whose correction falls below this (radii) is not passed again
    settled = 0.01
    #: it finds nearly every node (held-out recall 0.93-1.0 per scene), so a tracked node's match
    #: that no other detection competes for is that node, not an undetected neighbour
    #: (:attr:`~agents.perception.tracking.TrackerConfig.trust_uncontested`)
    finds_neighbours = True
    #: its circles are the spheres' outlines (trained so), never a print's square: a print's size against its
    #: circle tells whether the circle is its node's (:class:`~agents.perception.read_owner.PrintScale`)
    outlines_spheres = True

    def __init__(self, config: LearnedConfig | None = None):
        self.config = cfg = config or LearnedConfig()
        if not 0.0 < cfg.threshold < 1.0 or cfg.refine_passes < 0 or cfg.threads < 1:
            raise InputError("threshold must lie in (0, 1), refine_passes >= 0, threads >= 1", field="LearnedConfig")
        self.net = OnnxNet(cfg.model, cfg.backend, cfg.threads)
        #: (width, height) of the proposal network's input, from the model file
        self.input_size = model_input_size(cfg.model)
        #: the second-stage file in use (the 8-bit copy or the float network), None without one
        self.refine_path = None if cfg.refine_passes == 0 else second_stage_path(cfg, cfg.backend)
        self.refiner = None if self.refine_path is None else OnnxNet(self.refine_path, cfg.backend, cfg.threads)
        # as for the other detectors: the per-frame arrays (the resized frame, the network's input,
        # the crops) come from and go back to the heap instead of faulting fresh pages in every
        # frame (agents.perception.heap): 34.8 -> 32.7 ms per table1 frame for the whole front end
        keep_freed_memory()

    def proposals(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The first network's circles (n, 3) u, v, r in image pixels and their heatmap peaks (n,)."""
        img = np.asarray(image)
        if img.ndim == 2:
            img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
        img = img[..., :3]
        h, w = img.shape[:2]
        iw, ih = self.input_size
        pw, ph = max(w, int(np.ceil(h * iw / ih))), max(h, int(np.ceil(w * ih / iw)))
        if (pw, ph) != (w, h):  # pad (bottom and right) to the input's aspect ratio
            img = cv2.copyMakeBorder(img, 0, ph - h, 0, pw - w, cv2.BORDER_REPLICATE)
        small = cv2.resize(img, (iw, ih), interpolation=cv2.INTER_AREA)
        out = self.net.run(_to_input(small[None]))[0]
        return decode(out, pw / iw, self.config.threshold, self.stride)

    def refine(self, image: np.ndarray, circles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The second network's circles (n, 3) for proposals ``circles`` (n, 3), ``refine_passes`` times,
        and the size of each circle's last correction (n,) in radii (0 without a second stage)."""
        if self.refiner is None or not len(circles):
            return circles, np.zeros(len(circles))
        img = np.asarray(image)
        if img.ndim == 2:
            img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
        img = img[..., :3]
        c = circles.copy()
        moved = np.full(len(c), np.inf)
        active = np.ones(len(c), bool)  # circles still moving (a settled one keeps its last correction)
        for _ in range(self.config.refine_passes):
            idx = np.nonzero(active)[0]
            if not len(idx):
                break
            x = np.stack([refine_input(crop_circle(img, u, v, r, CROP_SIZE)) for u, v, r in c[idx]])
            d = self.refiner.run(_to_input(x)).astype(np.float64)
            d = np.clip(d, [-0.5, -0.5, np.log(0.6)], [0.5, 0.5, np.log(1.6)])
            r = c[idx, 2]
            c[idx] = np.column_stack([c[idx, 0] + d[:, 0] * r, c[idx, 1] + d[:, 1] * r, r * np.exp(d[:, 2])])
            moved[idx] = np.maximum(np.hypot(d[:, 0], d[:, 1]), np.abs(np.expm1(d[:, 2])))
            active[idx] = moved[idx] > self.settled
        return c, moved

    def detect(self, image: np.ndarray) -> list[Circle]:
        """Circles, best heatmap peak first."""
        img = np.asarray(image)
        if img.size == 0 or img.ndim not in (2, 3):
            return []
        cfg = self.config
        circles, scores = self.proposals(img)
        circles, moved = self.refine(img, circles)
        ok = (circles[:, 2] >= cfg.min_radius) & (circles[:, 2] <= cfg.max_radius) & (moved <= cfg.converge)
        circles, scores = circles[ok], scores[ok]
        kept: list[Circle] = []
        for i in np.argsort(-scores, kind="stable"):
            u, v, r = circles[i]
            if any(np.hypot(u - k.u, v - k.v) < cfg.overlap * max(r, k.r) for k in kept):
                continue
            kept.append(Circle(float(u), float(v), float(r), float(min(max(scores[i], 0.0), 1.0))))
        return kept
