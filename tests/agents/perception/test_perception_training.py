"""The learned detector's training pipeline: shards -> training -> ONNX that the detector loads (PyTorch only here)."""

import json

import numpy as np
import pytest

from agents.perception.training.data import (
    detector_targets,
    load_shards,
    shard_from_frames,
    write_shard,
)
from decentral.errors import InputError
from sims.lab.experiments.varied_scenes import sequence


def _shards(tmp_path, seeds=(2000, 2001, 2002)):
    """Tiny shards of 256 x 192 varied frames (2 frames each)."""
    paths = []
    for seed in seeds:
        seq = sequence(seed, 2, width=256, height=192, radius=(8.0, 30.0))
        arrays = shard_from_frames((f.image, [(s.u, s.v, s.r, v) for s, v in zip(f.spheres, f.visible)]) for f in seq)
        path = tmp_path / f"varied-{seed}.npz"
        write_shard(path, arrays)
        paths.append(path)
    return paths


def test_targets_peak_at_each_visible_centre_and_ignore_hidden_spheres():
    """A shown sphere gets heatmap 1 at its centre cell with its log radius; a mostly hidden one is masked out."""
    heat, weight, reg = detector_targets(np.array([[50.0, 30.0, 12.0, 1.0], [150.0, 100.0, 20.0, 0.1]]), (48, 64))
    cx, cy = (50.5 / 4 - 0.5), (30.5 / 4 - 0.5)
    iy, ix = int(round(cy)), int(round(cx))
    assert heat[iy, ix] == 1.0 and reg[3].sum() == 1.0
    np.testing.assert_allclose(reg[:3, iy, ix], [np.log(12.0), cx - ix, cy - iy], atol=1e-6)
    assert weight[round(100.5 / 4 - 0.5), round(150.5 / 4 - 0.5)] == 0.0


def test_shards_load_with_frame_indices_and_crops(tmp_path):
    """Loaded shards keep every frame's circles (in input pixels) and one crop per circle."""
    paths = _shards(tmp_path, (2000, 2001))
    data = load_shards(paths)
    assert data.images.shape == (4, 192, 256, 3) and len(data.crops) == len(data.circles) == data.first[-1]
    assert np.all(np.diff(data.circles[:, 0]) >= 0)
    assert data.frame_circles(3).shape[1] == 4


def test_bad_shard_is_an_input_error(tmp_path):
    """A file that is not a shard raises InputError naming it."""
    bad = tmp_path / "x.npz"
    bad.write_text("nope")
    with pytest.raises(InputError, match="x.npz"):
        load_shards([bad])


def test_labelled_frames_become_a_shard(tmp_path):
    """A user's labels JSON and images give a shard with their circles; a bad entry names its field."""
    import cv2

    from agents.perception.training.data import shard_from_labels

    img = np.full((192, 256, 3), 90, np.uint8)
    cv2.circle(img, (100, 80), 20, (200, 60, 60), -1)
    cv2.imwrite(str(tmp_path / "a.png"), img)
    (tmp_path / "labels.json").write_text(json.dumps({"frames": [{"image": "a.png", "circles": [[100, 80, 20]]}]}))
    arrays = shard_from_labels(tmp_path / "labels.json")
    np.testing.assert_allclose(arrays["circles"], [[0, 100, 80, 20, 1]])
    (tmp_path / "bad.json").write_text(json.dumps({"frames": [{"image": "a.png", "circles": [[1, 2]]}]}))
    with pytest.raises(InputError, match=r"frames\[0\]"):
        shard_from_labels(tmp_path / "bad.json")


def test_training_runs_end_to_end_and_the_detector_loads_its_onnx(tmp_path):
    """A few steps on tiny shards write both ONNX files, loss curves, and the detector runs them."""
    pytest.importorskip("torch", reason="training needs PyTorch (the `train` extra)")
    from agents.perception.learned import LearnedCircleDetector, LearnedConfig
    from agents.perception.training.__main__ import main

    _shards(tmp_path)
    out = tmp_path / "model"
    assert main(["train", str(tmp_path), "-o", str(out), "--steps", "3", "--refine-steps", "3", "--batch", "2",
                 "--eval-every", "3", "--validation", "varied-2002.npz"]) == 0
    for name in ("circles", "circle_refine"):
        log = json.loads((out / f"{name}_training.json").read_text())
        assert len(log["train"]) == 3 and log["validation"] and np.isfinite(log["validation"][-1]["loss"])
        assert (out / f"{name}_training.png").stat().st_size > 0
    image = sequence(2003, 1, width=256, height=192)[0].image
    for backend in ("opencv", "onnxruntime"):
        if backend == "onnxruntime":
            pytest.importorskip("onnxruntime")
        det = LearnedCircleDetector(LearnedConfig(model=out / "circles.onnx", refine_model=out / "circle_refine.onnx",
                                                  threshold=0.05, backend=backend))
        circles = det.detect(image)
        assert all(np.isfinite([c.u, c.v, c.r]).all() and c.r > 0 for c in circles)


def test_same_seed_gives_the_same_model(tmp_path):
    """Two short trainings from one seed give the same weights up to 1e-5; another seed does not."""
    torch = pytest.importorskip("torch", reason="training needs PyTorch (the `train` extra)")
    from agents.perception.training.train import TrainConfig, train

    paths = _shards(tmp_path)
    data, val = load_shards(paths[:2]), load_shards(paths[2:])
    weights = []
    for k, seed in enumerate((4, 4, 5)):
        train("detector", data, val, tmp_path / f"m{k}", TrainConfig(steps=2, batch=2, eval_every=2, seed=seed),
              progress=None)
        weights.append(torch.load(tmp_path / f"m{k}" / "circles.pt"))
    a, b, c = (torch.cat([v.flatten().float() for v in w.values()]) for w in weights)
    assert torch.allclose(a, b, atol=1e-5, rtol=0)
    assert not torch.allclose(a, c, atol=1e-3, rtol=0)


def test_cli_refuses_missing_shards_with_one_line(tmp_path, capsys):
    """Training on a folder without shards exits 2 with one line naming the folder."""
    from agents.perception.training.__main__ import main

    assert main(["train", str(tmp_path), "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(tmp_path) in err[0]


def test_only_the_training_modules_import_torch():
    """torch is imported by agents/perception/training/{model,train}.py only, and the package loads without it."""
    import ast
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[3]
    allowed = {"agents/perception/training/model.py", "agents/perception/training/train.py"}
    offenders = []
    for layer in ("decentral", "protocols", "agents", "sims"):
        for path in (root / layer).rglob("*.py"):
            tree = ast.parse(path.read_text(), filename=str(path))
            names = [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names]
            names += [n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module]
            rel = str(path.relative_to(root))
            offenders += [rel for n in names if n.split(".")[0] == "torch" and rel not in allowed]
    assert not offenders, offenders
    code = ("import sys\nimport agents.perception, agents.perception.learned, agents.perception.training.data\n"
            "from sims.cli.main import build_parser\nbuild_parser()\nassert 'torch' not in sys.modules\n")
    subprocess.run([sys.executable, "-c", code], check=True, cwd=root)


@pytest.mark.slow
def test_train_detector_command_renders_and_trains(tmp_path):
    """`decentral train-detector` renders shards, fine-tunes both shipped networks for a few steps and writes both ONNX
    files and the second stage's 8-bit copy."""
    pytest.importorskip("torch", reason="training needs PyTorch (the `train` extra)")
    from agents.perception.learned import MODEL_DIR
    from sims.cli.main import main

    out = tmp_path / "det"
    assert main(["train-detector", str(out), "--varied", "2008:2010", "--varied-frames", "1", "--table1", "100:100",
                 "--hard", "5049:5050", "--mottled", "6008:6010", "--ring", "300:301", "--ring-steps", "1",
                 "--steps", "2", "--refine-steps", "2", "--init", str(MODEL_DIR)]) == 0
    assert (out / "circles.onnx").is_file() and (out / "circle_refine.onnx").is_file()
    assert (out / "circle_refine_int8.onnx").is_file()
    assert json.loads((out / "circles_training.json").read_text())["init"].endswith("circles.onnx")
    assert sorted(p.name for p in (out / "shards").glob("*.npz")) == ["hard-5049.npz", "mottled-6008.npz",
                                                                        "mottled-6009.npz", "ring-300.npz",
                                                                        "varied-2008.npz", "varied-2009.npz"]


def test_hard_scenes_are_reproducible_and_cut_spheres_at_the_frame_edge():
    """The harder training scenes repeat from their seed, and some of their spheres are cut by the frame's edge."""
    from sims.lab.experiments.hard_scenes import hard_sequence

    a, b = hard_sequence(5003, 2, width=256, height=192, radius=(6.0, 28.0)), hard_sequence(5003, 2, width=256,
                                                                                             height=192, radius=(6.0, 28.0))
    assert all(np.array_equal(x.image, y.image) for x, y in zip(a, b))
    cut = 0
    for seed in range(5000, 5006):
        for f in hard_sequence(seed, 1, width=256, height=192, radius=(6.0, 28.0)):
            assert f.image.shape == (192, 256, 3) and len(f.spheres) == len(f.visible)
            assert ((f.visible >= 0) & (f.visible <= 1)).all()
            cut += sum(min(s.u, s.v, 255 - s.u, 191 - s.v) < 0.5 * s.r for s in f.spheres)
    assert cut > 0


def test_pair_scenes_are_reproducible_and_hold_small_spheres_that_touch_or_overlap(tmp_path):
    """Group scenes repeat from their seed; in their first frame most spheres of 12-45 px have a neighbour
    whose disc touches or overlaps theirs (centres drawn at most 1.1 times the radii's sum apart; 1.25 allows
    for the first frame's motion and size wobble);
    the command writes them as ``pairs-SEED.npz`` shards."""
    from sims.lab.experiments.detector_data import main as render_shards
    from sims.lab.experiments.hard_scenes import pair_sequence

    a, b = pair_sequence(8001, 2), pair_sequence(8001, 2)
    assert all(np.array_equal(x.image, y.image) for x, y in zip(a, b))
    small = touching = 0
    for seed in range(8000, 8008):
        f = pair_sequence(seed, 1)[0]
        assert f.image.shape == (768, 1024, 3) and ((f.visible >= 0) & (f.visible <= 1)).all()
        for i, s in enumerate(f.spheres):
            if s.r > 46:
                continue
            small += 1
            touching += any(np.hypot(s.u - o.u, s.v - o.v) <= 1.25 * (s.r + o.r) for j, o in enumerate(f.spheres) if j != i)
    assert small >= 16 and touching >= 0.8 * small
    assert render_shards([str(tmp_path), "--pairs", "8000:8001", "--pairs-frames", "2", "--input-size", "192x144"]) == 0
    with np.load(tmp_path / "pairs-8000.npz") as shard:
        assert shard["images"].shape[:3] == (2, 144, 192) and len(shard["circles"]) >= 4


def test_overlap_scenes_hold_large_spheres_partly_hidden_behind_smaller_ones(tmp_path):
    """Unequal-size group scenes repeat from their seed and keep the earlier group scenes' draws (a default
    ``ratio`` changes nothing); in their first frames some sphere of 45 px or more overlaps a smaller one at
    most 0.8 times its size (the case a network taught on equal small pairs leaves out); the command writes
    them as ``overlap-SEED.npz`` shards."""
    from sims.lab.experiments.detector_data import main as render_shards
    from sims.lab.experiments.hard_scenes import overlap_sequence, pair_sequence

    a, b = overlap_sequence(8201, 2), overlap_sequence(8201, 2)
    assert all(np.array_equal(x.image, y.image) for x, y in zip(a, b))
    assert np.array_equal(pair_sequence(8001, 1)[0].image, pair_sequence(8001, 1, ratio=(0.75, 1.33))[0].image)
    behind = 0
    for seed in range(8200, 8208):
        f = overlap_sequence(seed, 1)[0]
        assert ((f.visible >= 0) & (f.visible <= 1)).all()
        radii = [s.r for s in f.spheres]
        assert min(radii) >= 11.5 and max(radii) <= 111
        behind += sum(any(o.r <= 0.8 * s.r and np.hypot(s.u - o.u, s.v - o.v) < s.r + o.r for o in f.spheres)
                      for s in f.spheres if s.r >= 45)
    assert behind >= 4
    assert render_shards([str(tmp_path), "--overlap", "8200:8201", "--overlap-frames", "2", "--input-size", "192x144"]) == 0
    with np.load(tmp_path / "overlap-8200.npz") as shard:
        assert shard["images"].shape[:3] == (2, 144, 192) and len(shard["circles"]) >= 4


def test_mottled_scenes_are_reproducible_have_empty_floors_and_keep_their_held_out_seeds_out(tmp_path):
    """Mottled frames repeat from their seed; some frames hold no disc; every truth circle is a drawn disc
    (bright against its surroundings where fully visible); held-out seeds are refused as training data."""
    from sims.lab.experiments.detector_data import main as render_shards
    from sims.lab.experiments.mottled_scenes import HELD_OUT_MOTTLED_SEEDS, mottled_frames

    a, b = mottled_frames(6001, 6, width=320, height=240), mottled_frames(6001, 6, width=320, height=240)
    assert all(np.array_equal(x.image, y.image) and np.array_equal(x.circles, y.circles) for x, y in zip(a, b))
    frames = [f for seed in range(6000, 6008) for f in mottled_frames(seed, 4, width=320, height=240)]
    assert any(len(f.circles) == 0 for f in frames) and any(len(f.circles) > 0 for f in frames)
    for f in frames:
        assert f.image.shape == (240, 320, 3) and len(f.circles) == len(f.visible)
        assert ((f.visible >= 0) & (f.visible <= 1)).all()
    assert render_shards([str(tmp_path), "--mottled", f"{HELD_OUT_MOTTLED_SEEDS[0]}:{HELD_OUT_MOTTLED_SEEDS[0] + 1}"]) == 2
    assert not list(tmp_path.glob("*.npz"))


def test_ring_shards_are_reproducible_vary_their_wall_and_keep_the_experiments_runs_out(tmp_path):
    """A ring shard (the ``multi`` scenario, cameras at the spheres' height) repeats from its seed, seeds
    draw different walls above the horizon, its circles lie in the frames, and the seeds the experiments
    and benchmarks render (below TRAIN_RING_SEEDS) are refused."""
    from sims.lab.experiments.detector_data import TRAIN_RING_SEEDS, main as render_shards, ring_shard

    a, b = ring_shard(TRAIN_RING_SEEDS, 1, input_size=(192, 144)), ring_shard(TRAIN_RING_SEEDS, 1, input_size=(192, 144))
    assert all(np.array_equal(a[k], b[k]) for k in a)
    c = ring_shard(TRAIN_RING_SEEDS + 1, 1, input_size=(192, 144))
    assert not np.allclose(a["images"][:, 0].mean(axis=(0, 1)), c["images"][:, 0].mean(axis=(0, 1)), atol=2)  # top rows: wall
    for shard in (a, c):
        frame, u, v, r = shard["circles"][:, :4].T
        full = shard["scale"][frame.astype(int)] * np.array([192, 144])[:, None]
        assert len(frame) and (u >= -r).all() and (u <= full[0] + r).all() and (v <= full[1] + r).all()
    assert render_shards([str(tmp_path), "--ring", f"{TRAIN_RING_SEEDS - 1}:{TRAIN_RING_SEEDS}"]) == 2
    assert not list(tmp_path.glob("*.npz"))


def test_shipped_networks_load_back_into_torch_for_fine_tuning(tmp_path):
    """The shipped ONNX networks, loaded back into the torch networks, give onnxruntime's outputs (eval mode)."""
    pytest.importorskip("torch", reason="training needs PyTorch (the `train` extra)")
    pytest.importorskip("onnxruntime")
    import cv2

    from agents.perception.learned import MODEL_DIR, model_input_size
    from agents.perception.training.data import to_input
    from agents.perception.training.model import RefineNet
    from agents.perception.training.train import circlenet_from_onnx, load_onnx_weights

    size = model_input_size(MODEL_DIR / "circles.onnx")
    frames = to_input(np.stack([cv2.resize(f.image, size, interpolation=cv2.INTER_AREA)
                                for f in sequence(2000, 3, width=512, height=384)]))
    assert load_onnx_weights(circlenet_from_onnx(MODEL_DIR / "circles.onnx"), MODEL_DIR / "circles.onnx", [frames]) < 1e-4
    windows = to_input(np.random.default_rng(0).integers(0, 255, (8, 32, 32, 3)))
    assert load_onnx_weights(RefineNet(), MODEL_DIR / "circle_refine.onnx", [windows]) < 1e-4


def test_device_is_recorded_and_a_missing_gpu_is_one_line(tmp_path, capsys):
    """--device cpu trains and records the device; --device cuda without a GPU exits 2 naming --device."""
    torch = pytest.importorskip("torch", reason="training needs PyTorch (the `train` extra)")
    from agents.perception.training.__main__ import main

    _shards(tmp_path)
    args = ["train", str(tmp_path), "--network", "detector", "--steps", "1", "--batch", "2", "--eval-every", "1",
            "--validation", "varied-2002.npz"]
    assert main([*args, "-o", str(tmp_path / "cpu"), "--device", "cpu"]) == 0
    assert json.loads((tmp_path / "cpu" / "circles_training.json").read_text())["device"] == "cpu"
    if not torch.cuda.is_available():
        assert main([*args, "-o", str(tmp_path / "gpu"), "--device", "cuda"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "--device" in err[0]


def test_batch_workers_change_nothing(tmp_path):
    """Batches prepared by worker processes give the same weights as batches prepared in the training process.

    Ten steps with one worker pass each of its five shared input buffers on a second time: a buffer
    written again too early would change the weights."""
    torch = pytest.importorskip("torch", reason="training needs PyTorch (the `train` extra)")
    from agents.perception.training.train import TrainConfig, train

    paths = _shards(tmp_path)
    data, val = load_shards(paths[:2]), load_shards(paths[2:])
    weights = []
    for workers in (0, 1, 2):
        cfg = TrainConfig(steps=10, batch=2, eval_every=10, seed=3, device="cpu", workers=workers)
        train("detector", data, val, tmp_path / f"w{workers}", cfg, progress=None)
        weights.append(torch.cat([v.flatten().float() for v in torch.load(tmp_path / f"w{workers}" / "circles.pt").values()]))
    assert torch.allclose(weights[0], weights[1], atol=1e-5, rtol=0)
    assert torch.allclose(weights[0], weights[2], atol=1e-5, rtol=0)


def test_a_fine_tune_is_validated_before_its_first_step(tmp_path):
    """A fine-tune's step 0 is its starting network's validation loss: the best loss of the run it starts from."""
    pytest.importorskip("torch", reason="training needs PyTorch (the `train` extra)")
    from agents.perception.training.train import TrainConfig, train

    paths = _shards(tmp_path)
    data, val = load_shards(paths[:2]), load_shards(paths[2:])
    cfg = TrainConfig(steps=4, batch=2, eval_every=2, seed=3, device="cpu")
    first = train("detector", data, val, tmp_path / "a", cfg, progress=None)
    assert [e["step"] for e in first["validation"]] == [2, 4]  # (no step 0 without a starting network)
    tuned = train("detector", data, val, tmp_path / "b", cfg, progress=None, init=tmp_path / "a" / "circles.pt")
    start = tuned["validation"][0]
    assert start["step"] == 0
    assert start["loss"] == pytest.approx(min(e["loss"] for e in first["validation"]), rel=1e-5)
    assert tuned["best_step"] in (0, 2, 4) and (tmp_path / "b" / "circles.onnx").is_file()


def test_detector_takes_its_input_size_from_the_model(tmp_path):
    """A proposal network trained on 384 x 288 frames is run at 384 x 288 (read from the ONNX file) and finds circles."""
    pytest.importorskip("torch", reason="training needs PyTorch (the `train` extra)")
    from agents.perception.learned import LearnedCircleDetector, LearnedConfig, model_input_size
    from agents.perception.training.__main__ import main

    for seed in (2000, 2001):
        seq = sequence(seed, 1, width=384, height=288, radius=(10.0, 40.0))
        frames = [(f.image, [(s.u, s.v, s.r, v) for s, v in zip(f.spheres, f.visible)]) for f in seq]
        write_shard(tmp_path / f"varied-{seed}.npz", shard_from_frames(frames, input_size=(384, 288)))
    out = tmp_path / "m"
    assert main(["train", str(tmp_path), "-o", str(out), "--network", "detector", "--steps", "1", "--batch", "1",
                 "--eval-every", "1", "--width", "16", "--channels", "8", "16", "16", "24", "32", "--device", "cpu",
                 "--validation", "varied-2001.npz"]) == 0
    assert model_input_size(out / "circles.onnx") == (384, 288)
    det = LearnedCircleDetector(LearnedConfig(model=out / "circles.onnx", refine_model=None, threshold=0.01))
    assert det.input_size == (384, 288)
    image = sequence(2003, 1)[0].image  # 1024 x 768
    assert all(np.isfinite([c.u, c.v, c.r]).all() for c in det.detect(image))


def test_quantized_second_stage_is_written_beside_the_model_and_run_by_onnxruntime(tmp_path):
    """`quantize` writes <stem>_int8.onnx beside the model (byte-identical for the same seed) and a report;
    the detector runs it with onnxruntime, the float network with OpenCV or quantized=False."""
    pytest.importorskip("onnx", reason="quantizing needs the onnx package (the `train` extra)")
    pytest.importorskip("onnxruntime")
    import shutil

    from agents.perception.learned import MODEL_DIR, LearnedCircleDetector, LearnedConfig, second_stage_path
    from agents.perception.training.__main__ import main

    shards = tmp_path / "shards"
    shards.mkdir()
    _shards(shards, seeds=(2000, 2009))
    model = tmp_path / "m" / "circle_refine.onnx"
    model.parent.mkdir()
    shutil.copy(MODEL_DIR / "circle_refine.onnx", model)
    args = ["quantize", str(shards), "--model", str(model), "--samples", "64", "--validation", "varied-*9.npz"]
    assert main(args) == 0
    copy = model.with_name("circle_refine_int8.onnx")
    report = json.loads(copy.with_suffix(".json").read_text())
    assert report["calibration_windows"] == 64 and report["validation"]["windows"] == 64
    assert max(report["validation"]["max"]) < 0.1  # radii: a broken calibration moves circles by far more
    first = copy.read_bytes()
    assert main(args) == 0 and copy.read_bytes() == first
    assert not list(model.parent.glob("*.tmp"))

    cfg = LearnedConfig(refine_model=model)
    assert second_stage_path(cfg, "onnxruntime") == copy
    assert second_stage_path(cfg, "opencv") == model
    assert second_stage_path(LearnedConfig(refine_model=model, quantized=False), "onnxruntime") == model
    assert LearnedCircleDetector(cfg).refine_path == copy


def test_quantize_refuses_a_missing_or_broken_model_with_one_line(tmp_path, capsys):
    """A missing --model, or a file that is no network, ends with exit status 2, one line naming the file and
    nothing written."""
    pytest.importorskip("onnx", reason="quantizing needs the onnx package (the `train` extra)")
    from agents.perception.training.__main__ import main

    shards = tmp_path / "shards"
    shards.mkdir()
    _shards(shards, seeds=(2000, 2009))
    missing, junk = tmp_path / "nope.onnx", tmp_path / "junk.onnx"
    junk.write_bytes(b"not a network")
    for model in (missing, junk):
        assert main(["quantize", str(shards), "--model", str(model), "--validation", "varied-*9.npz"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and str(model) in err[0]
        assert not list(tmp_path.glob(f"{model.stem}_int8*"))
