"""Rendered frames: circle geometry, readable tags, occlusion order, and the frame writers."""

import cv2
import numpy as np
import pytest

from render_helpers import tiny_world
from sims.simulation.render.effects import motion_kernel
from sims.simulation.render.frame_files import write_frames
from sims.simulation.render.renderer import RenderConfig, Renderer
from sims.simulation.scenarios import get_scenario, simulate


def _render(world, *, config=None, k=0, seed=0):
    renderer = Renderer(world, config or RenderConfig.clean(), np.random.default_rng(seed))
    rig = world.cameras[0]
    return renderer, rig, renderer.render_linear(rig, k)


def _mask_circle(mask):
    i, j = np.nonzero(mask)
    return j.mean(), i.mean(), np.sqrt(mask.sum() / np.pi)


@pytest.mark.parametrize("pos", [(1.2, 0.0, 0.34), (1.0, 0.15, 0.25), (1.8, -0.3, 0.1), (0.9, -0.1, 0.45)])
def test_clean_sphere_near_the_axis_matches_the_projected_circle(pos):
    """Within ~12 deg of the axis the drawn sphere's centre is within 1 px and radius within 3 % of eq. (1)'s circle."""
    _, _, (buf, _, circles) = _render(tiny_world([(5, pos)]))
    u, v, r = _mask_circle(buf.ids == 5)
    cu, cv, cr = circles[5][:3]
    assert np.hypot(u - cu, v - cv) < 1.0
    assert abs(r - cr) / cr < 0.03


@pytest.mark.parametrize("pos", [(1.0, 0.3, 0.2), (1.5, -0.6, 0.34), (0.8, -0.35, 0.34), (2.0, 0.5, 0.06)])
def test_clean_sphere_anywhere_matches_its_exact_silhouette(pos):
    """Anywhere in view the drawn sphere matches the exact silhouette ellipse's centre and area."""
    _, rig, (buf, _, circles) = _render(tiny_world([(5, pos)]))
    u, v, r = _mask_circle(buf.ids == 5)
    su, sv, sr = circles[5][3:]
    assert np.hypot(u - su, v - sv) < 0.3
    assert abs(r - sr) / sr < 0.01


def _read_tags(image, circle):
    u, v, r = circle
    pad = int(1.5 * r)
    roi = image[max(int(v) - pad, 0):int(v) + pad, max(int(u) - pad, 0):int(u) + pad]
    detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11),
                                       cv2.aruco.DetectorParameters())
    _, ids, _ = detector.detectMarkers(cv2.cvtColor(roi, cv2.COLOR_BGR2GRAY))
    return set() if ids is None else {int(i) for i in ids.ravel()}


@pytest.mark.parametrize("node, yaw", [(37, 0.0), (212, np.pi / 2), (5, np.radians(230))])
def test_tag_facing_the_camera_is_readable(node, yaw):
    """OpenCV's 36h11 detector reads the node id from a clean frame of a sphere facing the camera."""
    world = tiny_world([(node, (0.75, 0.0, 0.3))], yaw=yaw)
    renderer = Renderer(world, RenderConfig.clean(), np.random.default_rng(0))
    frame = renderer.render(world.cameras[0], 0, np.random.default_rng(1))
    (rec,) = frame.nodes
    assert _read_tags(frame.image, (rec["u"], rec["v"], rec["r"])) == {node}


def test_nearer_sphere_hides_the_farther_one():
    """Where two spheres overlap in the image the nearer one is drawn, whatever the drawing order."""
    near, far = (1.0, 0.0, 0.34), (1.6, 0.05, 0.34)
    _, rig, (buf, sil, circles) = _render(tiny_world([(1, near), (2, far)]))
    _, _, (buf2, _, _) = _render(tiny_world([(2, far), (1, near)]))
    assert np.array_equal(buf.ids, buf2.ids) and np.allclose(buf.colour, buf2.colour)
    u, v = circles[2][:2]
    assert buf.ids[int(round(v)), int(round(u))] == 1
    frame = Renderer(tiny_world([(1, near), (2, far)]), RenderConfig.clean(), np.random.default_rng(0)).render(
        rig, 0, np.random.default_rng(0))
    vis = {n["id"]: n["visible"] for n in frame.nodes}
    assert vis[1] == 1.0 and 0.0 < vis[2] < 0.6


def test_struts_are_drawn_between_nodes_and_occlude():
    """A strut joining two nodes is drawn between them and hides the floor behind it."""
    _, _, (buf, _, circles) = _render(tiny_world([(3, (1.2, -0.15, 0.34)), (4, (1.2, 0.15, 0.34))], struts=True))
    u = int(round((circles[3][0] + circles[4][0]) / 2))
    v = int(round((circles[3][1] + circles[4][1]) / 2))
    assert buf.ids[v, u] == -2


def test_effects_are_reproducible_and_seeded():
    """The same seed gives the same noisy frame; another seed a different one."""
    world = tiny_world([(5, (1.2, 0.0, 0.34))])
    rig = world.cameras[0]
    frames = [Renderer(world, RenderConfig(), np.random.default_rng(0)).render(rig, 1, np.random.default_rng(s)).image
              for s in (3, 3, 4)]
    assert np.array_equal(frames[0], frames[1]) and not np.array_equal(frames[0], frames[2])


def test_wall_settings_change_the_wall_only():
    """``wall_levels`` / ``wall_tint`` paint the wall above the horizon (top and bottom rows at the given
    brightness times the tint); the floor and the sphere stay as they were. Values outside [0, 1] are refused."""
    world = tiny_world([(5, (1.2, 0.0, 0.34))])
    _, _, (plain, _, _) = _render(world)
    _, _, (dark, _, _) = _render(world, config=RenderConfig.clean(wall_levels=(0.3, 0.2), wall_tint=(1.0, 0.5, 0.8)))
    wall = ~np.isfinite(plain.depth) & (plain.ids == -1)
    assert wall[0].all() and wall.any(axis=1).sum() > 10
    assert np.allclose(dark.colour[~wall], plain.colour[~wall])
    assert np.allclose(dark.colour[0, 0], 0.3 * np.array([1.0, 0.5, 0.8]), atol=1e-6)
    last = np.flatnonzero(wall.all(axis=1))[-1]  # the lowest row that is wall from edge to edge
    expected = 0.3 + (0.2 - 0.3) * last / (len(wall) - 1)
    assert np.allclose(dark.colour[last, 0], expected * np.array([1.0, 0.5, 0.8]), atol=1e-6)
    for bad in ({"wall_levels": (0.3,)}, {"wall_levels": (1.2, 0.5)}, {"wall_tint": (1.0, 0.5, -0.1)}):
        with pytest.raises(ValueError, match="wall_"):
            RenderConfig(**bad)


def test_motion_kernel_is_a_normalized_line():
    """A motion of (6, 0) px blurs along a horizontal line of weights summing to 1."""
    k = motion_kernel(6.0, 0.0)
    assert k.sum() == pytest.approx(1.0)
    rows = np.nonzero(k.sum(axis=1))[0]
    assert len(rows) == 1 and np.count_nonzero(k) >= 6
    assert motion_kernel(0.3, 0.2) is None


def test_png_frames_and_truth_records(tmp_path):
    """PNG mode writes one file per camera and step and records each frame's visible nodes."""
    sim = simulate(get_scenario("table1", steps=2, noise=False), seed=0)
    paths, frames = write_frames(sim, tmp_path, mode="png")
    assert sorted(p.relative_to(tmp_path).as_posix() for p in paths) == [
        "frames/A0/cam0/00000.png", "frames/A0/cam0/00001.png"]
    img = cv2.imread(str(paths[0]))
    assert img.shape == (768, 1024, 3)
    rec = frames[0]["A0/cam0"]
    assert rec["file"] == "frames/A0/cam0/00000.png"
    seen = {n["id"] for n in rec["nodes"] if n["visible"] > 0.5}
    assert {v["id"] for v in sim.truth.visible[0]["A0/cam0"]} <= seen | {v["id"] for v in sim.truth.visible[0]["A0/cam0"] if v["covered"] > 0.3}


def test_video_mode_writes_a_readable_video(tmp_path):
    """Video mode writes one video per camera holding every step."""
    sim = simulate(get_scenario("single_node", steps=3), seed=0)
    paths, _ = write_frames(sim, tmp_path, mode="video")
    (path,) = paths
    cap = cv2.VideoCapture(str(path))
    n = 0
    while cap.read()[0]:
        n += 1
    assert n == 3 and not list(tmp_path.rglob("*.part*"))
