"""The ONNX circle-head loader, on a tiny centre-surround network the test builds itself."""

import numpy as np
import pytest

onnx = pytest.importorskip("onnx")
from onnx import TensorProto, helper  # noqa: E402

from agents.perception.onnx_head import OnnxCircleDetector, OnnxHeadConfig  # noqa: E402
from decentral.errors import InputError  # noqa: E402

H, W, R = 96, 128, 12.0


def _kernel(r):
    """Centre-surround kernel: +1 on a disc of radius r, -1 on the ring out to 1.45 r (zero mean)."""
    k = int(np.ceil(1.45 * r))
    y, x = np.mgrid[-k:k + 1, -k:k + 1]
    d = np.hypot(x, y)
    inner, ring = d <= r, (d > r) & (d <= 1.45 * r)
    ker = np.where(inner, 1.0 / inner.sum(), 0.0) - np.where(ring, 1.0 / ring.sum(), 0.0)
    return ker.astype(np.float32), k


def _model(path, r=R):
    ker, k = _kernel(r)
    gain = 40.0  # a bright disc on a dark ground scores about sigmoid(40 * 0.5 - 12)
    w_heat = helper.make_tensor("w_heat", TensorProto.FLOAT, [1, 1, 2 * k + 1, 2 * k + 1], (gain * ker).ravel())
    b_heat = helper.make_tensor("b_heat", TensorProto.FLOAT, [1], [-12.0])
    w_rad = helper.make_tensor("w_rad", TensorProto.FLOAT, [1, 1, 1, 1], [0.0])
    b_rad = helper.make_tensor("b_rad", TensorProto.FLOAT, [1], [r])
    nodes = [
        helper.make_node("Conv", ["image", "w_heat", "b_heat"], ["logit"], pads=[k, k, k, k]),
        helper.make_node("Sigmoid", ["logit"], ["heatmap"]),
        helper.make_node("Conv", ["image", "w_rad", "b_rad"], ["radius"]),
    ]
    graph = helper.make_graph(
        nodes, "circle_head",
        [helper.make_tensor_value_info("image", TensorProto.FLOAT, [1, 1, H, W])],
        [helper.make_tensor_value_info("heatmap", TensorProto.FLOAT, [1, 1, H, W]),
         helper.make_tensor_value_info("radius", TensorProto.FLOAT, [1, 1, H, W])],
        initializer=[w_heat, b_heat, w_rad, b_rad],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    onnx.save(model, str(path))
    return path


def _disc_image(u, v, r, scale=1):
    y, x = np.mgrid[0:H * scale, 0:W * scale].astype(float)
    alpha = np.clip(r * scale - np.hypot(x - u * scale, y - v * scale) + 0.5, 0, 1)
    return (30 + 180 * alpha).astype(np.uint8)


def test_tiny_head_finds_the_disc_and_refinement_makes_it_exact(tmp_path):
    """The head's peak lands on the disc; the rim refinement brings it within 0.5 px and 3 %."""
    det = OnnxCircleDetector(_model(tmp_path / "m.onnx"), OnnxHeadConfig(input_size=(W, H), channels=1))
    circles = det.detect(_disc_image(60.3, 41.7, R))
    assert len(circles) == 1
    c = circles[0]
    assert np.hypot(c.u - 60.3, c.v - 41.7) < 0.5 and abs(c.r - R) / R < 0.03


def test_image_larger_than_the_input_is_scaled_back(tmp_path):
    """A 2x larger image is resized to the input and the circle comes back in image pixels."""
    det = OnnxCircleDetector(_model(tmp_path / "m.onnx"), OnnxHeadConfig(input_size=(W, H), channels=1))
    (c,) = det.detect(_disc_image(60.0, 40.0, R, scale=2))
    assert np.hypot(c.u - 119.5, c.v - 79.5) < 1.0 and abs(c.r - 2 * R) / (2 * R) < 0.03


def test_empty_image_gives_no_circle(tmp_path):
    """A uniform image yields no peak above the threshold."""
    det = OnnxCircleDetector(_model(tmp_path / "m.onnx"), OnnxHeadConfig(input_size=(W, H), channels=1))
    assert det.detect(np.full((H, W), 30, np.uint8)) == []


def test_corrupt_model_file_is_an_input_error(tmp_path):
    """A file that is not an ONNX model raises InputError naming it."""
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"not a model")
    with pytest.raises(InputError) as err:
        OnnxCircleDetector(bad)
    assert err.value.source == str(bad)
