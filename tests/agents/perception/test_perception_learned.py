"""The shipped learned detector (``detector="learned"``): package data, both runtimes, rendered truth."""

import numpy as np
import pytest

from agents.perception import Perception, make_detector
from agents.perception.learned import MODEL_DIR, LearnedCircleDetector, LearnedConfig, decode
from agents.perception.types import CircleDetector
from decentral.errors import InputError
from sims.lab.experiments.varied_scenes import HELD_OUT_SEEDS, TUNING_SEEDS, sequence


def _strict(c, s):
    """The benchmark's strict match: centre within max(2 px, 0.1 r), radius within 10 %."""
    return np.hypot(c.u - s.u, c.v - s.v) <= max(2.0, 0.1 * s.r) and abs(c.r - s.r) <= 0.1 * s.r


def test_shipped_networks_are_package_data_and_load_without_torch():
    """Both ONNX files and the model card ship in agents/perception/models and the detector builds from them."""
    for name in ("circles.onnx", "circle_refine.onnx", "circles.md"):
        assert (MODEL_DIR / name).is_file(), name
    det = make_detector("learned")
    assert isinstance(det, LearnedCircleDetector) and isinstance(det, CircleDetector)
    assert isinstance(Perception("learned").detector, LearnedCircleDetector)


def test_decoding_the_training_targets_gives_back_the_circles():
    """Perfect network outputs (the training targets) decode to the true circles within 1e-6 px."""
    from agents.perception.training.data import detector_targets

    truth = np.array([[100.3, 200.7, 30.0], [700.2, 500.9, 60.0]])
    heat, _, reg = detector_targets(np.column_stack([truth / 4.0, np.ones(2)]), (48, 64))
    circles, scores = decode(np.stack([heat, reg[0], reg[1], reg[2]]), 4.0, 0.5)
    np.testing.assert_allclose(circles[np.argsort(circles[:, 0])], truth, atol=1e-5)
    assert np.all(scores == 1.0)


def test_opencv_and_onnxruntime_backends_agree():
    """cv2.dnn and onnxruntime give the same circles within 0.01 px on a rendered frame (float networks)."""
    pytest.importorskip("onnxruntime")
    image = sequence(TUNING_SEEDS[3], 1)[0].image
    a = LearnedCircleDetector(LearnedConfig(backend="opencv")).detect(image)
    b = LearnedCircleDetector(LearnedConfig(backend="onnxruntime", quantized=False)).detect(image)
    assert len(a) == len(b) > 0
    np.testing.assert_allclose([[c.u, c.v, c.r] for c in a], [[c.u, c.v, c.r] for c in b], atol=1e-2)


def test_shipped_8_bit_second_stage_finds_the_float_networks_circles():
    """With onnxruntime the shipped detector runs the 8-bit second stage; on tuning scenes 0-7 it finds the
    circles the float one finds, each centre within 3 % and radius within 2 % of the radius (measured with the
    current networks: at most 0.9 % and 1.2 %, median 0.2 px). A proposal at the heatmap threshold may settle on a rim in one and not in
    the other: at most one such circle a frame, with a score under 0.35, is kept by one stage only."""
    pytest.importorskip("onnxruntime")
    quantized = LearnedCircleDetector(LearnedConfig(backend="onnxruntime"))
    float_ = LearnedCircleDetector(LearnedConfig(backend="onnxruntime", quantized=False))
    assert quantized.refine_path.name == "circle_refine_int8.onnx"
    assert float_.refine_path.name == "circle_refine.onnx"
    assert LearnedCircleDetector(LearnedConfig(backend="opencv")).refine_path.name == "circle_refine.onnx"
    for seed in TUNING_SEEDS[:8]:
        image = sequence(seed, 2)[1].image
        a = np.array([[c.u, c.v, c.r, c.score] for c in float_.detect(image)])
        b = np.array([[c.u, c.v, c.r, c.score] for c in quantized.detect(image)])
        assert len(a) > 0 and len(b) > 0, seed
        gap = np.hypot(a[:, None, 0] - b[None, :, 0], a[:, None, 1] - b[None, :, 1])
        near = gap <= 0.03 * a[:, None, 2]
        only = [(a, near.any(axis=1)), (b, near.any(axis=0))]
        assert sum(int((~found).sum()) for _, found in only) <= 1, seed
        assert all(np.all(circles[~found, 3] < 0.35) for circles, found in only), seed
        matched = near.any(axis=1)
        nearest = gap.argmin(axis=1)
        assert np.all(np.abs(b[nearest, 2] - a[:, 2])[matched] <= 0.02 * a[matched, 2]), seed


def test_finds_the_spheres_of_unseen_varied_scenes_within_the_strict_tolerance():
    """On tuning scenes 0-3 (never trained on), >= 90 % of the spheres showing >= 90 % match strictly, <= 5 % false circles."""
    hit = total = false = 0
    det = make_detector("learned")
    for seed in TUNING_SEEDS[:4]:
        assert seed not in HELD_OUT_SEEDS
        fr = sequence(seed, 2)[1]
        circles = det.detect(fr.image)
        for s, vis in zip(fr.spheres, fr.visible):
            if vis >= 0.9:
                total += 1
                hit += any(_strict(c, s) for c in circles)
        false += sum(all(np.hypot(c.u - s.u, c.v - s.v) > s.r for s in fr.spheres) for c in circles)
    assert hit >= 0.9 * total, (hit, total)
    assert false <= 0.05 * total, (false, total)


def test_empty_and_uniform_frames_give_no_circle():
    """An empty array and a uniform grey frame give no circle."""
    det = make_detector("learned")
    assert det.detect(np.zeros((0, 0, 3), np.uint8)) == []
    assert det.detect(np.full((768, 1024, 3), 128, np.uint8)) == []


def test_grey_and_other_aspect_ratio_frames_are_accepted():
    """A grey frame and a 16:9 frame run (padded to 4:3) and give finite circles inside the frame."""
    fr = sequence(TUNING_SEEDS[5], 1)[0]
    det = make_detector("learned")
    grey = det.detect(fr.image[:, :, 1].copy())
    wide = det.detect(fr.image[:576].copy())
    for c in grey + wide:
        assert np.isfinite([c.u, c.v, c.r]).all() and c.r > 0


def test_input_size_is_read_from_the_onnx_file_as_onnxruntime_reads_it(tmp_path):
    """The ONNX input shape read from the file equals onnxruntime's; the detector's input size is that shape's W, H;
    a file that is not ONNX is an InputError naming it."""
    ort = pytest.importorskip("onnxruntime")
    from agents.perception.onnx_shape import onnx_input_shape

    for name in ("circles.onnx", "circle_refine.onnx"):
        want = [d if isinstance(d, int) else None for d in
                ort.InferenceSession(str(MODEL_DIR / name), providers=["CPUExecutionProvider"]).get_inputs()[0].shape]
        assert list(onnx_input_shape(MODEL_DIR / name)) == want
    n, c, h, w = onnx_input_shape(MODEL_DIR / "circles.onnx")
    assert make_detector("learned").input_size == (w, h)
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"\xff\xff\xff")
    for read in (onnx_input_shape, lambda p: LearnedCircleDetector(LearnedConfig(model=p, backend="onnxruntime"))):
        with pytest.raises(InputError, match="bad.onnx"):
            read(bad)


def test_missing_model_and_unknown_backend_are_input_errors(tmp_path):
    """A missing model file or an unknown backend raises InputError naming it."""
    with pytest.raises(InputError, match="nope.onnx"):
        LearnedCircleDetector(LearnedConfig(model=tmp_path / "nope.onnx"))
    with pytest.raises(InputError, match="backend"):
        LearnedCircleDetector(LearnedConfig(backend="tensorrt"))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_discs_of_another_renderer_match_strictly_and_within_one_and_a_half_pixels_and_three_percent_median(seed):
    """On the synthetic disc frames (not the training renderer) every disc matches strictly (centre within
    max(2 px, 0.1 r), radius within 10 %), with median errors under 1.5 px and 3 % (hough: 1 px, 3 % each)."""
    from perception_scenes import frame, layout

    nodes = layout(seed)
    circles = make_detector("learned").detect(frame(nodes, seed=seed))
    centre, radius = [], []
    for n in nodes:
        near = [c for c in circles if np.hypot(c.u - n.u, c.v - n.v) < 0.3 * n.r]
        assert near, f"disc at ({n.u:.0f}, {n.v:.0f}) r={n.r:.0f} missed"
        centre.append(np.hypot(near[0].u - n.u, near[0].v - n.v))
        radius.append(abs(near[0].r - n.r) / n.r)
        assert centre[-1] <= max(2.0, 0.1 * n.r) and radius[-1] <= 0.1
    assert np.median(centre) < 1.5 and np.median(radius) < 0.03


def test_few_false_circles_on_mottled_floors_it_was_not_trained_on():
    """On held-out mottled floors (blotches 6-48 px, 64 frames) and on the perception tests' blotchy floor at
    1024 x 768, at most one false circle a frame on average (the release before the mottled floors proposed 6.3
    and 28; the current networks 0.125 and 0), and at least 85 % of the whole discs found strictly (0.98)."""
    from agents.perception.types import TrackedCircle
    from sims.lab.experiments.mottled_scenes import HELD_OUT_MOTTLED_SEEDS, mottled_frames
    from sims.lab.experiments.perception_scores import SequenceScore, score_frame
    from sims.lab.experiments.synthetic_scene import SceneConfig, SceneNode, draw_scene, floor_texture

    det = make_detector("learned")
    frames = [f for seed in HELD_OUT_MOTTLED_SEEDS for f in mottled_frames(seed, 4)]
    score = SequenceScore()
    for f in frames:
        score_frame(score, f, [TrackedCircle(c, None, None, None) for c in det.detect(f.image)], min_visible=0.9)
    assert score.false_circles <= len(frames) and score.counted > 20 and score.matched >= 0.85 * score.counted, score
    false = 0
    for seed in range(4):
        floor = floor_texture(1024, 768, np.random.default_rng(1000 + seed))
        image = draw_scene([SceneNode(300.0, 380.0, 40.0, tag=77, tag_size=0.75)], SceneConfig(noise=2.0),
                           np.random.default_rng(seed), floor=floor)
        false += sum(np.hypot(c.u - 300.0, c.v - 380.0) > 20 for c in det.detect(image))
    assert false <= 4, false
