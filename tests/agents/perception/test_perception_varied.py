"""The rim-finding detectors (`detector="rim"`, `"symmetry"`) on fixed varied frames: the rim, not the tag."""

import numpy as np
import pytest

from agents.perception import make_detector
from agents.perception.types import Circle, TagRead, TrackedCircle
from sims.lab.experiments.perception_scores import SequenceScore, score_frame
from sims.lab.experiments.varied_scenes import HELD_OUT_SEEDS, TUNING_SEEDS, Look, Sphere, Strut, render, sequence
from sims.simulation.render.surfaces import SURFACES, lighting_gradient, surface

W, H = 640, 480
RIM_DETECTORS = ("rim", "symmetry")
LOOK = Look(light=(-0.4, -0.5, 0.77), ambient=0.35, noise=2.0, blur=0.6)


def _frame(spheres, struts=(), kind="grey_grain", seed=3):
    rng = np.random.default_rng(seed)
    floor = surface(kind, rng, H, W)
    return render(tuple(spheres), tuple(struts), LOOK, floor, lighting_gradient(rng, H, W), rng), floor


def _on(circles, s, tol=0.5):
    return [c for c in circles if np.hypot(c.u - s.u, c.v - s.v) < tol * s.r]


def _matches(c, s):
    return np.hypot(c.u - s.u, c.v - s.v) <= max(2.0, 0.1 * s.r) and abs(c.r - s.r) <= 0.1 * s.r


@pytest.mark.parametrize("detector", RIM_DETECTORS)
@pytest.mark.parametrize("radius,delta", [(60.0, 0.0), (85.0, 0.02), (85.0, -0.03)])
def test_large_sphere_coloured_like_the_floor_gets_its_rim_not_its_tag(radius, delta, detector):
    """A 60-85 px sphere within 3 % of a carpet's colour gets one circle on its rim, not on its tag."""
    _, floor = _frame([], kind="carpet")
    grey = floor[H // 3:].reshape(-1, 3).mean(axis=0)
    s = Sphere(11, 320.0, 250.0, radius, tuple(float(c) for c in np.clip(grey + delta, 0, 1)),
               tag_normal=(0.15, -0.2, 0.97), tag_half_angle=0.45, paper=True, specular=0.2)
    fr, _ = _frame([s], kind="carpet")
    circles = _on(make_detector(detector).detect(fr.image), s)
    assert len(circles) == 1, circles
    assert _matches(circles[0], s), circles[0]


@pytest.mark.parametrize("detector", RIM_DETECTORS)
def test_tag_squeezed_at_the_limb_gives_no_second_circle(detector):
    """A large sphere whose tag sits near its limb gives exactly one circle, its rim (no concentric double)."""
    normal = np.array([0.75, 0.35, 0.56])
    s = Sphere(42, 300.0, 240.0, 70.0, (0.45, 0.5, 0.55), tag_normal=tuple(normal / np.linalg.norm(normal)),
               tag_half_angle=0.45, paper=True, specular=0.4)
    fr, _ = _frame([s], kind="tiles", seed=5)
    circles = [c for c in make_detector(detector).detect(fr.image) if np.hypot(c.u - s.u, c.v - s.v) < s.r]
    assert len(circles) == 1, circles
    assert _matches(circles[0], s), circles[0]


@pytest.mark.parametrize("detector", RIM_DETECTORS)
def test_partly_hidden_sphere_radius_comes_from_its_visible_rim(detector):
    """A sphere a third hidden behind a nearer one and crossed by a strut keeps its radius within 10 %."""
    far = Sphere(7, 260.0, 240.0, 48.0, (0.2, 0.35, 0.75), tag_normal=(-0.3, 0.2, 0.93), specular=0.3)
    near = Sphere(8, 340.0, 260.0, 66.0, (0.65, 0.55, 0.3), tag_normal=(0.2, -0.1, 0.97), specular=0.3)
    strut = Strut((180.0, 150.0), (300.0, 330.0), 9.0, (0.15, 0.15, 0.15))
    fr, _ = _frame([far, near], [strut], kind="wood", seed=7)
    assert 0.5 < fr.visible[0] < 0.8  # the farther (smaller) sphere is drawn first
    circles = make_detector(detector).detect(fr.image)
    for s in (far, near):
        found = _on(circles, s, tol=0.3)
        assert found and _matches(found[0], s), (s, found)


def test_sequences_are_reproducible_and_varied():
    """A scene seed gives the same frames every time; different seeds give different scenes."""
    a, b, c = sequence(5, 2, width=320, height=240), sequence(5, 2, width=320, height=240), sequence(6, 2, width=320, height=240)
    assert all(np.array_equal(x.image, y.image) for x, y in zip(a, b))
    assert not np.array_equal(a[0].image, c[0].image)
    assert all(15.0 <= s.r <= 90.0 for fr in a for s in fr.spheres) and 5 <= len(a[0].spheres) <= 10


def test_held_out_seeds_are_not_tuning_seeds():
    """No scene seed is both a tuning and a held-out seed."""
    assert not set(TUNING_SEEDS) & set(HELD_OUT_SEEDS)


@pytest.mark.parametrize("kind", sorted(SURFACES))
def test_every_surface_is_a_reflectance_image(kind):
    """Each floor or background kind is an (H, W, 3) float32 image in [0, 1] with texture."""
    img = surface(kind, np.random.default_rng(0), 96, 128)
    assert img.shape == (96, 128, 3) and img.dtype == np.float32
    assert 0.0 <= img.min() and img.max() <= 1.0 and img.std() > 0.005


def test_scorer_counts_matches_false_and_double_circles():
    """A circle on a sphere matches, a second one on it is a double, one on the floor is false, ids are checked."""
    s = Sphere(3, 100.0, 100.0, 30.0, (0.5, 0.5, 0.5))
    fr, _ = _frame([s])
    read = TagRead(3, 3, np.zeros((4, 2)), 0, 40.0, 1.0)
    dets = [TrackedCircle(Circle(101.0, 100.0, 29.0, 0.9), read, 3, 1),
            TrackedCircle(Circle(110.0, 100.0, 12.0, 0.6), None, 5, None),
            TrackedCircle(Circle(400.0, 300.0, 20.0, 0.6), None, None, None)]
    score = SequenceScore()
    score_frame(score, fr, dets)
    got = score.summary()
    assert got["recall"] == 1.0 and score.double_circles == 1 and score.false_circles == 1
    assert score.wrong_ids == 1 and score.shown_ids == 2
