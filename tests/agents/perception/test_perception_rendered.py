"""The detector and the sphere tag reader on frames of the project's renderer (clean table1 frames)."""

import numpy as np
import pytest

render = pytest.importorskip("sims.simulation.render.frame_files")

from agents.perception import HoughCircleDetector  # noqa: E402
from agents.perception.sphere import eq1_circle  # noqa: E402
from agents.perception.sphere_tags import SphereTagReader  # noqa: E402
from sims.simulation.render.renderer import RenderConfig  # noqa: E402
from sims.simulation.scenarios import get_scenario, simulate  # noqa: E402


@pytest.fixture(scope="module")
def clean_run():
    # the wider table1 geometry of the ranges below (targets 2.5 m away on average, nodes of 17-27 px): the pixel
    # thresholds below were set for it; the default geometry (1.85 m, as in the seed) is measured
    # by benchmarks/perception.py
    sim = simulate(get_scenario("table1", steps=6, noise=False, ranges=(1.8, 2.5, 2.0)), seed=4)
    frames = [f for _, key, f in render.render_frames(sim, 4, RenderConfig.clean()) if key == "A0/cam0"]
    return sim, frames


def _whole(n, w=1024, h=768):
    return n["visible"] >= 0.99 and n["su"] - n["sr"] >= 2 and n["sv"] - n["sr"] >= 2 and n["su"] + n["sr"] <= w - 3 and n["sv"] + n["sr"] <= h - 3


def test_rendered_clean_circles_within_one_pixel_and_three_percent(clean_run):
    """On clean rendered frames, most wholly visible nodes are found within 1 px and 3 % of their silhouette."""
    _, frames = clean_run
    det = HoughCircleDetector()
    good = total = 0
    centre, radius = [], []
    for f in frames:
        circles = det.detect(f.image)
        for n in filter(_whole, f.nodes):
            total += 1
            near = [c for c in circles if np.hypot(c.u - n["su"], c.v - n["sv"]) < 0.5 * n["sr"]]
            if not near:
                continue
            c = near[0]
            centre.append(np.hypot(c.u - n["su"], c.v - n["sv"]))
            radius.append(abs(c.r - n["sr"]) / n["sr"])
            good += centre[-1] < 1.0 and radius[-1] < 0.03
    assert total >= 10
    assert good >= 0.8 * total
    assert np.median(centre) < 0.5 and np.median(radius) < 0.01


def test_rendered_eq1_circles_match_the_projection(clean_run):
    """Converted to eq. (1) circles, detections match the projected centre and f r0 / z within 1 px and 2 %."""
    sim, frames = clean_run
    K = sim.log.cameras["A0/cam0"].K
    det = HoughCircleDetector()
    errs = []
    for f in frames:
        circles = det.detect(f.image)
        for n in filter(_whole, f.nodes):
            near = [c for c in circles if np.hypot(c.u - n["su"], c.v - n["sv"]) < 0.5 * n["sr"]]
            if near:
                c = eq1_circle(near[0], K)
                errs.append((np.hypot(c.u - n["u"], c.v - n["v"]), abs(c.r - n["r"]) / n["r"]))
    errs = np.array(errs)
    assert np.median(errs[:, 0]) < 1.0 and np.median(errs[:, 1]) < 0.02


def test_rendered_tags_read_with_the_sphere_model(clean_run):
    """Every wholly visible node of 20 px radius or more is identified, and no id is wrong."""
    sim, frames = clean_run
    log = sim.log
    reader = SphereTagReader()
    import cv2

    read = total = wrong = 0
    for k, f in enumerate(frames):
        grey = cv2.GaussianBlur(cv2.cvtColor(f.image, cv2.COLOR_BGR2GRAY).astype(np.float32), (0, 0), 0.5)
        R = log.camera_pose("A0/cam0", log.steps[k]).R
        nodes = [i for c in log.steps[k].config.values() for i in c]
        for n in f.nodes:
            if not _whole(n):
                continue
            from agents.perception.types import Circle

            r = reader.read(grey, Circle(n["u"], n["v"], n["r"], 1.0), log.cameras["A0/cam0"].K, R, log.node_radius, nodes)
            wrong += r is not None and r.node != n["id"]
            if n["r"] >= 20:
                total += 1
                read += r is not None and r.node == n["id"]
    assert wrong == 0
    assert total >= 5 and read == total
