"""The detector is a choice: ``"hough"`` (the default, the earlier pipeline unchanged), ``"rim"`` or ``"symmetry"``."""

import subprocess
import sys

import numpy as np
import pytest

from agents.perception import HoughCircleDetector, Perception, RimCircleDetector, make_detector

# circles (u, v, r, score) of HoughCircleDetector() on A0/cam0's three frames of
# simulate(get_scenario("table1", steps=3), seed=2) rendered with render_frames(sim, 5, RenderConfig()),
# produced by the detector as it was before the rim detector was added
BEFORE = [
    [[303.8077, 560.6381, 31.2232, 0.7188],
     [537.3239, 443.7496, 22.2541, 0.7188],
     [732.2901, 539.4688, 31.1444, 0.7031],
     [693.5978, 381.3814, 27.7441, 0.7031],
     [431.1593, 543.9785, 29.2458, 0.5625],
     [415.1027, 492.2888, 26.1361, 0.5312],
     [166.9103, 577.6409, 33.4232, 0.5156],
     [462.2919, 467.6425, 24.0717, 0.5156],
     [686.1187, 485.3773, 26.7175, 0.4844],
     [453.9187, 431.5522, 21.4573, 0.4844],
     [495.8599, 439.7823, 9.8021, 0.4375]],
    [[456.5408, 430.5176, 21.6511, 0.7812],
     [725.8964, 534.1959, 30.5972, 0.7656],
     [313.9641, 561.3467, 31.3282, 0.75],
     [351.6655, 556.9583, 10.5464, 0.7344],
     [692.7353, 378.3043, 27.4649, 0.7031],
     [540.6381, 440.9291, 21.9293, 0.6094],
     [441.8672, 545.7634, 29.1895, 0.5469],
     [468.5141, 465.5024, 23.9015, 0.5469],
     [178.4521, 576.6277, 33.4162, 0.4688],
     [427.4775, 493.7444, 26.4354, 0.4688],
     [684.552, 481.7646, 26.889, 0.3906]],
    [[325.1452, 563.3965, 31.3022, 0.7656],
     [721.6888, 529.5906, 30.1616, 0.7656],
     [693.672, 375.7036, 27.1373, 0.7031],
     [469.7291, 462.7352, 18.7179, 0.6406],
     [453.6394, 549.6231, 29.5668, 0.5781],
     [543.8001, 438.1462, 21.6197, 0.5781],
     [440.3075, 495.0067, 25.579, 0.4375],
     [685.5129, 478.3432, 26.6748, 0.4219],
     [191.7968, 580.8706, 36.4423, 0.3906]],
]


def test_default_is_the_hough_detector_and_rim_is_opt_in():
    """Perception() and make_detector() build the Hough detector; "rim" builds the rim detector; others fail."""
    assert isinstance(Perception().detector, HoughCircleDetector)
    assert isinstance(make_detector(), HoughCircleDetector)
    assert isinstance(Perception("rim").detector, RimCircleDetector)
    rim = make_detector("rim", 10.2, 90.5)
    assert isinstance(rim, RimCircleDetector) and (rim.config.min_radius, rim.config.max_radius) == (10, 91)
    with pytest.raises(ValueError, match="unknown detector"):
        make_detector("canny")


def test_default_detector_reproduces_the_earlier_detections_on_rendered_table1():
    """On rendered table1 frames the default detector returns exactly the circles it returned before the rim option."""
    render = pytest.importorskip("sims.render.frames")
    from sims.render.renderer import RenderConfig
    from sims.scenarios import get_scenario, simulate

    sim = simulate(get_scenario("table1", steps=3), seed=2)
    frames = [f for _, key, f in render.render_frames(sim, 5, RenderConfig()) if key == "A0/cam0"]
    det = make_detector("hough")
    got = [[[c.u, c.v, c.r, c.score] for c in det.detect(f.image)] for f in frames]
    assert [len(g) for g in got] == [len(e) for e in BEFORE]
    for g, e in zip(got, BEFORE):
        np.testing.assert_allclose(np.array(g), np.array(e), atol=1e-4)


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
    from sims.experiments.synthetic_scene import SceneConfig, SceneNode, draw_scene, floor_texture

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
