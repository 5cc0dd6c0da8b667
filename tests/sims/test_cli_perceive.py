"""``decentral perceive``: the contract's detections format, log assembly, and bad input."""

import json

import cv2
import numpy as np
import pytest

from sims.cli.main import main
from sims.lab.experiments.synthetic_scene import SceneConfig, SceneNode, draw_scene, floor_texture
from sims.io.detections_json import read_detections



def _frames(tmp_path, count=4, tags=(5, 9)):
    floor = floor_texture(640, 480, np.random.default_rng(0))
    paths = []
    for k in range(count):
        nodes = [SceneNode(150 + 10 * k, 200, 35, tag=tags[0]), SceneNode(450 - 10 * k, 260, 30, tag=tags[1] if k != 2 else None)]
        img = draw_scene(nodes, SceneConfig(width=640, height=480, noise=1.0), np.random.default_rng(k), floor=floor)
        p = tmp_path / f"f{k:04d}.png"
        cv2.imwrite(str(p), img)
        paths.append(str(p))
    return paths


def test_perceive_writes_the_contract_format(tmp_path):
    """The output has the contract's format, one frame per input, and the fields of each detection."""
    paths = _frames(tmp_path)
    out = tmp_path / "dets.json"
    assert main(["perceive", *paths, "-o", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["format"] == "decentral.detections/1"
    assert [f["source"] for f in doc["frames"]] == paths
    for f in doc["frames"]:
        for d in f["detections"]:
            assert {"u", "v", "r", "score", "id", "track"} <= set(d)


def test_perceive_tracks_ids_through_a_missing_tag(tmp_path):
    """The node whose tag is missing in frame 2 still carries its id there, on the same track."""
    out = tmp_path / "dets.json"
    assert main(["perceive", *_frames(tmp_path), "-o", str(out)]) == 0
    frames = read_detections(out)
    ids = [sorted(d.node for d in f.detections if d.node is not None) for f in frames]
    assert ids == [[5, 9]] * 4


def test_no_track_leaves_untagged_detections_unnamed(tmp_path):
    """With --no-track, the detection without a tag read has id null and no track."""
    out = tmp_path / "dets.json"
    assert main(["perceive", *_frames(tmp_path), "-o", str(out), "--no-track"]) == 0
    frame2 = read_detections(out)[2]
    assert sorted(d.node for d in frame2.detections if d.node is not None) == [5]
    assert all(d.track is None for d in frame2.detections)


def test_video_input(tmp_path):
    """One video file is read frame by frame, sources named file#index."""
    paths = _frames(tmp_path, count=3)
    video = tmp_path / "clip.avi"
    w = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 5, (640, 480))
    if not w.isOpened():
        pytest.skip("no MJPG encoder in this OpenCV build")
    for p in paths:
        w.write(cv2.imread(p))
    w.release()
    out = tmp_path / "dets.json"
    assert main(["perceive", str(video), "-o", str(out)]) == 0
    assert [f.source for f in read_detections(out)] == ["clip.avi#0", "clip.avi#1", "clip.avi#2"]


@pytest.mark.parametrize("content", [b"", b"not an image at all", b"\x89PNG\r\n\x1a\n\x00\x00broken"])
def test_corrupt_image_exits_2_naming_the_file(tmp_path, capsys, content):
    """A corrupt frame ends with exit 2, a one-line message naming it, and no output file."""
    paths = _frames(tmp_path, count=2)
    bad = tmp_path / "bad.png"
    bad.write_bytes(content)
    out = tmp_path / "dets.json"
    assert main(["perceive", paths[0], str(bad), paths[1], "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "bad.png" in err and err.count("\n") == 1 and "Traceback" not in err
    assert not out.exists()


def test_missing_frame_exits_2(tmp_path, capsys):
    """A frame that does not exist ends with exit 2 naming it."""
    out = tmp_path / "dets.json"
    assert main(["perceive", str(tmp_path / "nope.png"), "-o", str(out)]) == 2
    assert "nope.png" in capsys.readouterr().err and not out.exists()


def test_unknown_family_exits_2(tmp_path, capsys):
    """An unknown tag family ends with exit 2 naming --family."""
    out = tmp_path / "dets.json"
    assert main(["perceive", *_frames(tmp_path, count=1), "-o", str(out), "--family", "tag99h1"]) == 2
    assert "--family" in capsys.readouterr().err and not out.exists()


def test_log_template_options_go_together(tmp_path, capsys):
    """--log-template without --camera and --log-out is refused with exit 2."""
    out = tmp_path / "dets.json"
    assert main(["perceive", *_frames(tmp_path, count=1), "-o", str(out), "--log-template", "x.json"]) == 2
    assert "--log-template" in capsys.readouterr().err


def test_log_assembly_from_a_rendered_run(tmp_path):
    """Frames of a rendered run + its log template give a decentral.log/1 with identified detections."""
    pytest.importorskip("sims.simulation.render")
    from sims.io.log_json import read_log

    run = tmp_path / "run"
    assert main(["simulate", "table1", "-o", str(run), "--steps", "3", "--frames", "png", "--seed", "2"]) == 0
    frames = sorted(str(p) for p in (run / "frames").rglob("*.png"))
    out, log_out = tmp_path / "dets.json", tmp_path / "log.json"
    assert main(["perceive", *frames, "-o", str(out), "--log-template", str(run / "log.json"),
                 "--camera", "A0/cam0", "--log-out", str(log_out)]) == 0
    log = read_log(log_out)
    truth = json.loads((run / "truth.json").read_text())
    seen = 0
    for k, step in enumerate(log.steps):
        true = {n["id"]: n for n in truth["steps"][k]["frames"]["A0/cam0"]["nodes"]}
        for d in step.detections.get("A0/cam0", ()):
            assert d.node in true
            t = true[d.node]
            assert np.hypot(d.u - t["u"], d.v - t["v"]) < 0.3 * t["r"]
            seen += 1
    assert seen >= 3


def test_auto_motion_uses_the_logs_odometry_not_registration(tmp_path, monkeypatch):
    """With a log template that has odometry, the default motion source is the odometry (no image registration)."""
    pytest.importorskip("sims.simulation.render")
    from agents.perception import motion

    def no_flow(self, *args, **kwargs):
        raise AssertionError("image registration ran although the log has odometry")

    run = tmp_path / "run"
    assert main(["simulate", "table1", "-o", str(run), "--steps", "3", "--frames", "png", "--seed", "2"]) == 0
    frames = sorted(str(p) for p in (run / "frames").rglob("*.png"))
    monkeypatch.setattr(motion.FlowRegistration, "__call__", no_flow)
    used = []
    real = motion.odometry_homography
    monkeypatch.setattr(motion, "odometry_homography", lambda *a: used.append(1) or real(*a))
    out, log_out = tmp_path / "dets.json", tmp_path / "log.json"
    assert main(["perceive", *frames, "-o", str(out), "--log-template", str(run / "log.json"),
                 "--camera", "A0/cam0", "--log-out", str(log_out)]) == 0
    assert len(used) == len(frames) - 1


def test_the_commands_offer_every_detector_and_default_to_the_librarys_default():
    """perceive and experiment spell the detector names out (importing the detectors loads OpenCV): the same names
    and the same default as agents.perception.detectors."""
    import argparse

    from agents.perception.detectors import DEFAULT_DETECTOR, DETECTORS
    from sims.cli import experiment, perceive
    from sims.lab.experiments.table1 import TableConfig

    for module in (perceive, experiment):
        parser = argparse.ArgumentParser()
        module.add_arguments(parser)
        action = next(a for a in parser._actions if a.dest == "detector")
        assert sorted(action.choices) == sorted(DETECTORS) and action.default == DEFAULT_DETECTOR
    assert TableConfig().detector == DEFAULT_DETECTOR
