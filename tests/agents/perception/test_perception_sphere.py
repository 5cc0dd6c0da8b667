"""Sphere geometry: eq. (1) circles from silhouettes, and the model-based reading of curved prints."""

import cv2
import numpy as np
import pytest

from agents.perception.circle_fit import fit_circles_algebraic
from agents.perception.sphere import eq1_circle
from agents.perception.sphere_tags import SphereTagConfig, SphereTagIdentifier, SphereTagReader, StickerLayout
from agents.perception.types import Circle

K = np.array([[760.0, 0, 512], [0, 760.0, 384], [0, 0, 1]])
R0 = 0.06
# camera looking along the root's +x (x right, y down, z forward), as the contract's example mount
R_CAM = np.array([[0.0, 0, 1], [-1, 0, 0], [0, -1, 0]])


def _silhouette_circle(C):
    """Best circle (algebraic) through the exact silhouette of the sphere at C (camera frame)."""
    d = np.linalg.norm(C)
    a = C / d
    e1 = np.cross(a, [0, 1.0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(a, e1)
    s = R0 / d
    c = np.sqrt(1 - s * s)
    t = np.linspace(0, 2 * np.pi, 200, endpoint=False)
    rays = c * a[None] + s * (np.cos(t)[:, None] * e1 + np.sin(t)[:, None] * e2)
    pix = rays @ K.T
    pts = pix[:, :2] / pix[:, 2:]
    (fit,), _ = fit_circles_algebraic(pts[None], np.ones((1, len(pts))))
    return Circle(*fit, 1.0)


@pytest.mark.parametrize("C", [(0.0, 0.0, 2.0), (0.9, 0.5, 1.6), (-1.1, 0.6, 2.2)])
def test_eq1_circle_recovers_the_sphere_centre(C):
    """From the silhouette's circle, the eq. (1) circle back-projects to the sphere centre within 0.3 %."""
    C = np.array(C)
    circ = eq1_circle(_silhouette_circle(C), K)
    centre = np.linalg.solve(K, [circ.u, circ.v, 1.0]) * (K[0, 0] * R0 / circ.r)
    assert np.linalg.norm(centre - C) / np.linalg.norm(C) < 3e-3


def _render(tag, yaw, C, layout, size=(768, 1024)):
    """Ray-cast one tagged sphere (node yaw ``yaw`` in the root frame) on a grey background, grey image."""
    h, w = size
    ys, xs = np.mgrid[0:h, 0:w].astype(float)
    rays = np.stack([xs, ys, np.ones_like(xs)], -1) @ np.linalg.inv(K).T
    a = np.einsum("hwk,hwk->hw", rays, rays)
    b = rays @ C
    disc = b * b - a * (C @ C - R0 * R0)
    img = np.full((h, w), 110.0)
    hit = disc >= 0
    t = (b[hit] - np.sqrt(disc[hit])) / a[hit]
    n_cam = (rays[hit] * t[:, None] - C) / R0
    Rz = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
    n_node = n_cam @ (R_CAM.T @ Rz)  # rows: R_node^T n with R_node = R_cam^T Rz
    if layout is None:  # a plain sphere
        img[hit] = 215.0
        return cv2.GaussianBlur(img, (0, 0), 0.6).astype(np.float32)
    code = cv2.aruco.generateImageMarker(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11), tag, 8, borderBits=1) > 127
    dots = n_node @ layout.axes.T
    best = np.argmax(dots, axis=1)
    along = dots[np.arange(len(best)), best]
    s1 = np.arctan2(np.einsum("pk,pk->p", n_node, layout.right[best]), along)
    s2 = np.arctan2(np.einsum("pk,pk->p", n_node, layout.up[best]), along)
    hh = layout.half_angle
    inside = (np.abs(s1) < hh) & (np.abs(s2) < hh)
    col = np.clip(((s1 / hh + 1) * 4).astype(int), 0, 7)
    row = np.clip(((1 - s2 / hh) * 4).astype(int), 0, 7)
    val = np.where(inside, np.where(code[row, col], 230.0, 25.0), 215.0)
    img[hit] = val
    img = cv2.GaussianBlur(img, (0, 0), 0.6)
    return img.astype(np.float32)


def _eq1(C):
    p = K @ C
    return Circle(p[0] / p[2], p[1] / p[2], K[0, 0] * R0 / C[2], 1.0)


@pytest.mark.parametrize("tag, yaw", [(31, 0.3), (120, 2.0), (7, -1.2)])
def test_curved_print_on_a_22px_node_is_read(tag, yaw):
    """A tag printed on a 22 px node 2 m away (about 2 px per cell) is read with its id."""
    layout = StickerLayout.around()
    C = np.array([0.2, 0.1, 2.07])
    read = SphereTagReader(SphereTagConfig(layout=layout)).read(_render(tag, yaw, C, layout), _eq1(C), K, R_CAM, R0)
    assert read is not None and read.tag == tag and read.hamming == 0


def test_sphere_reader_rejects_a_plain_sphere():
    """A sphere without print gives no read, whatever the candidates."""
    layout = StickerLayout.around(top=False)
    C = np.array([0.0, 0.0, 2.0])
    img = _render(5, 0.0, C, None)
    assert SphereTagReader(SphereTagConfig(layout=layout)).read(img, _eq1(C), K, R_CAM, R0) is None


def test_sphere_identifier_respects_candidates():
    """Restricted to other tags' codes, the identifier does not name the node."""
    layout = StickerLayout.around()
    C = np.array([0.0, 0.0, 1.8])
    img = _render(44, 0.5, C, layout).astype(np.uint8)
    ident = SphereTagIdentifier(K, R0, SphereTagConfig(layout=layout), blur=0.0)
    ident.set_view(R_CAM, [44, 45])
    assert ident.identify(img, [_eq1(C)])[0].tag == 44
    ident.set_view(R_CAM, [45, 46])
    assert ident.identify(img, [_eq1(C)]) == [None]


def test_overlapping_equator_stickers_are_refused():
    """A layout whose equator stickers would overlap is rejected (the renderer and reader share it)."""
    with pytest.raises(ValueError):
        StickerLayout.around(n_equator=8, half_angle=0.5)


def test_batched_eq1_circles_match_the_single_conversion():
    """eq1_circles over many circles gives what eq1_circle gives one at a time."""
    from agents.perception.sphere import eq1_circles
    from agents.perception.types import Circle

    K = np.array([[760.0, 0, 512], [0, 760.0, 384], [0, 0, 1]])
    rng = np.random.default_rng(3)
    C = np.column_stack([rng.uniform(0, 1024, 30), rng.uniform(0, 768, 30), rng.uniform(8, 150, 30)])
    batch, ok = eq1_circles(C, K)
    assert ok.all()
    for c, b in zip(C, batch):
        one = eq1_circle(Circle(*c, 1.0), K)
        assert np.allclose([one.u, one.v, one.r], b, atol=1e-9)
