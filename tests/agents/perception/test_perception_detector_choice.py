"""The detector is a choice: ``"hough"`` (the default), ``"rim"`` or ``"symmetry"``."""

import subprocess
import sys

import numpy as np
import pytest

from agents.perception import HoughCircleDetector, Perception, RimCircleDetector, make_detector

#: a node counts as unoccluded when this fraction of its silhouette is visible
UNOCCLUDED = 0.95
#: a node is found when a circle's centre and radius are within this fraction of its silhouette radius
FOUND_WITHIN = 0.1
#: share of the unoccluded nodes that must be found (16 of 18 on an AMD EPYC; the rest lie next to an
#: occluding node, where the circle shifts by 0.13-0.23 radii)
MIN_RECALL = 0.75
#: a circle at least this fraction of the frame's smallest node radius must lie on a node, within half
#: a radius of its centre (smaller circles are tag cells or edges, which the tag reader rejects)
NODE_SIZED = 0.6


def test_default_is_the_learned_detector_and_the_others_are_opt_in():
    """Perception() and make_detector() build the learned detector; "hough" and "rim" build theirs; others fail."""
    from agents.perception.learned import LearnedCircleDetector

    assert isinstance(Perception().detector, LearnedCircleDetector)
    assert isinstance(make_detector(), LearnedCircleDetector)
    assert isinstance(make_detector("hough"), HoughCircleDetector)
    assert isinstance(Perception("rim").detector, RimCircleDetector)
    rim = make_detector("rim", 10.2, 90.5)
    assert isinstance(rim, RimCircleDetector) and (rim.config.min_radius, rim.config.max_radius) == (10, 91)
    with pytest.raises(ValueError, match="unknown detector"):
        make_detector("canny")


def test_default_detector_finds_the_rendered_nodes_of_table1():
    """On rendered table1 frames the default detector finds at least 3 in 4 unoccluded nodes within a tenth
    of their radius (centre and radius), and every circle of a node's size lies on a node."""
    render = pytest.importorskip("sims.simulation.render.frame_files")
    from sims.simulation.render.renderer import RenderConfig
    from sims.simulation.scenarios import get_scenario, simulate

    sim = simulate(get_scenario("table1", steps=3), seed=2)
    frames = [f for _, key, f in render.render_frames(sim, 5, RenderConfig()) if key == "A0/cam0"]
    det = make_detector("hough")
    found = unoccluded = 0
    for f in frames:
        circles = det.detect(f.image)
        for n in f.nodes:
            if n["visible"] >= UNOCCLUDED:
                unoccluded += 1
                found += any(np.hypot(c.u - n["su"], c.v - n["sv"]) < FOUND_WITHIN * n["sr"]
                             and abs(c.r - n["sr"]) < FOUND_WITHIN * n["sr"] for c in circles)
        smallest = min(n["sr"] for n in f.nodes)
        for c in circles:
            if c.r >= NODE_SIZED * smallest:
                off = min(np.hypot(c.u - n["su"], c.v - n["sv"]) / n["sr"] for n in f.nodes)
                assert off < 0.5, f"circle ({c.u:.1f}, {c.v:.1f}, r={c.r:.1f}) lies on no node"
    assert unoccluded >= 12 and found >= MIN_RECALL * unoccluded, (found, unoccluded)


def test_perceive_help_documents_the_detector_choice():
    """`decentral perceive --help` names --detector with hough as the default and rim and symmetry as options."""
    out = subprocess.run([sys.executable, "-m", "sims.cli.main", "perceive", "--help"], capture_output=True, text=True,
                         check=True).stdout
    assert "--detector" in out and "hough" in out and "rim" in out and "symmetry" in out


@pytest.mark.parametrize("detector", ["rim", "symmetry"])
def test_perceive_runs_the_opt_in_detector_when_asked(tmp_path, detector):
    """`decentral perceive --detector rim|symmetry` writes detections with both tagged nodes found and named."""
    import json

    import cv2

    from sims.cli.main import main
    from sims.lab.experiments.synthetic_scene import SceneConfig, SceneNode, draw_scene, floor_texture

    floor = floor_texture(640, 480, np.random.default_rng(0))
    paths = []
    for k in range(3):
        nodes = [SceneNode(150 + 10 * k, 200, 35, tag=5), SceneNode(450 - 10 * k, 260, 30, tag=9)]
        img = draw_scene(nodes, SceneConfig(width=640, height=480, noise=1.0), np.random.default_rng(k), floor=floor)
        paths.append(str(tmp_path / f"f{k}.png"))
        cv2.imwrite(paths[-1], img)
    out = tmp_path / "dets.json"
    assert main(["perceive", *paths, "-o", str(out), "--detector", detector]) == 0
    last = json.loads(out.read_text())["frames"][-1]["detections"]
    found = {d["id"]: (d["u"], d["v"], d["r"]) for d in last if d["id"] is not None}
    assert set(found) == {5, 9}
    assert np.hypot(found[5][0] - 170, found[5][1] - 200) < 2 and abs(found[5][2] - 35) < 2
