"""Ellipse fits and the float blur used by the rim refinement (off-axis spheres image as ellipses)."""

import cv2
import numpy as np

from agents.perception import HoughCircleDetector
from agents.perception.circle_fit import ellipse_circles, fit_ellipses_direct, sampson_distances
from agents.perception.hough import _blur_float


def _ellipse_points(cx, cy, a, b, th, n=64):
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    x = cx + a * np.cos(t) * np.cos(th) - b * np.sin(t) * np.sin(th)
    y = cy + a * np.cos(t) * np.sin(th) + b * np.sin(t) * np.cos(th)
    return np.stack([x, y], axis=1)


def test_direct_ellipse_fit_recovers_centre_area_radius_and_axis():
    """Exact ellipse points give back the centre, sqrt(a b), the axis ratio and the major axis."""
    pts = _ellipse_points(300.0, 200.0, 50.0, 40.0, 0.7)[None]
    c0, s0 = np.array([[290.0, 210.0]]), np.array([45.0])
    conic, ok = fit_ellipses_direct(pts, np.ones((1, 64)), c0, s0)
    circles, ratio, major, cok = ellipse_circles(conic, c0, s0)
    assert ok.all() and cok.all()
    assert np.allclose(circles[0], [300.0, 200.0, np.sqrt(50.0 * 40.0)], atol=1e-6)
    assert np.isclose(ratio[0], 1.25)
    assert abs(abs(major[0] @ [np.cos(0.7), np.sin(0.7)]) - 1.0) < 1e-9
    assert np.abs(sampson_distances(pts, conic, c0, s0)).max() < 1e-6


def test_off_axis_sphere_ellipse_is_detected_with_its_area_radius():
    """A radially elongated bright ellipse (an off-axis sphere's image) is found within 1 px and 2 % of sqrt(a b)."""
    img = np.full((480, 640, 3), (70, 80, 90), np.uint8)
    # 271 px from the centre: a sphere there looks up to 1.14 times longer radially (f >= 500 px)
    cx, cy, a, b = 100.0, 80.0, 52.0, 46.0
    th = np.arctan2(cy - 239.5, cx - 319.5)  # major axis towards the image centre
    cv2.ellipse(img, ((cx, cy), (2 * a, 2 * b), np.degrees(th)), (200, 205, 210), -1, lineType=cv2.LINE_AA)
    img = cv2.GaussianBlur(img, (0, 0), 0.8)
    circles = HoughCircleDetector().detect(img)
    near = [c for c in circles if np.hypot(c.u - cx, c.v - cy) < 10]
    assert near
    c = near[0]
    assert np.hypot(c.u - cx, c.v - cy) < 1.0 and abs(c.r / np.sqrt(a * b) - 1.0) < 0.02


def test_float_blur_matches_gaussian_blur_of_the_float_image():
    """The uint8 -> float32 separable blur equals cv2.GaussianBlur on the float image."""
    img = np.random.default_rng(0).integers(0, 256, (60, 80, 3), dtype=np.uint8)
    for sigma in (0.5, 1.0, 2.0):
        ref = cv2.GaussianBlur(img.astype(np.float32), (0, 0), sigma)
        assert np.abs(_blur_float(img, sigma) - ref).max() < 1e-3


def test_blur_into_a_given_buffer_equals_a_fresh_blur():
    """_blur_float with ``out`` writes into that buffer the same values as without it."""
    rng = np.random.default_rng(3)
    img = rng.integers(0, 256, (40, 50, 3), dtype=np.uint8)
    buf = np.full((40, 50, 3), -1.0, np.float32)
    got = _blur_float(img, 1.0, out=buf)
    assert np.shares_memory(got, buf)
    assert np.array_equal(buf, _blur_float(img, 1.0))


def test_keep_freed_memory_is_idempotent():
    """keep_freed_memory answers a bool and the same answer on every call."""
    from agents.perception.heap import keep_freed_memory

    first = keep_freed_memory()
    assert isinstance(first, bool)
    assert keep_freed_memory() is first


def test_rim_points_outermost_edge_on_a_two_edge_ray():
    """The rim on a ray crossing a strong inner edge and a weaker outer one is the outer edge."""
    from agents.perception.refine import RefineConfig, rim_points

    img = np.full((200, 200), 40.0, np.float32)
    yy, xx = np.mgrid[:200, :200]
    d = np.hypot(xx - 100.0, yy - 100.0)
    img[d < 40] = 120.0  # the node (outer, weaker step of 80)
    img[d < 20] = 250.0  # a bright disc inside (stronger step of 130)
    img = cv2.GaussianBlur(img, (0, 0), 1.0)
    pts, strength = rim_points(img, np.array([[100.0, 100.0, 30.0]]), (0.5, 1.5), RefineConfig(), rays=16, samples=30)
    r = np.hypot(pts[0, :, 0] - 100.0, pts[0, :, 1] - 100.0)
    assert (strength[0] > 0).all()
    assert np.abs(r - 40.0).max() < 1.0


def test_algebraic_fit_exact_on_weighted_circle_points():
    """The batched algebraic fit recovers exact circles, ignoring zero-weight outliers."""
    from agents.perception.circle_fit import fit_circles_algebraic

    t = np.linspace(0.0, 2.0 * np.pi, 32, endpoint=False)
    truth = np.array([[100.0, 50.0, 20.0], [400.5, 300.25, 75.0]])
    pts = np.stack([truth[:, None, 0] + truth[:, None, 2] * np.cos(t), truth[:, None, 1] + truth[:, None, 2] * np.sin(t)], axis=2)
    w = np.ones((2, 32))
    pts[:, :5] += 30.0  # outliers, weighted out
    w[:, :5] = 0.0
    fit, ok = fit_circles_algebraic(pts, w)
    assert ok.all()
    assert np.abs(fit - truth).max() < 1e-8
