"""AprilTag identification inside circles: ids, filtering measures, tag table, tagless frames."""

import cv2
import numpy as np

from agents.perception import AprilTagConfig, AprilTagIdentifier
from agents.perception.apriltag import tag_quality
from agents.perception.types import Circle
from perception_scenes import frame, layout
from sims.lab.experiments.synthetic_scene import SceneNode


def _circles(nodes):
    return [Circle(n.u, n.v, n.r, 1.0) for n in nodes]


def test_tag_ids_recovered_on_clean_frames():
    """Every tag on clean 22-45 px discs is read with its id (node id = tag id by default)."""
    nodes = layout(0)
    reads = AprilTagIdentifier().identify(frame(nodes), _circles(nodes))
    assert [r.node if r else None for r in reads] == [n.tag for n in nodes]


def test_noisy_frames_give_no_wrong_id():
    """With noise sigma 8 and blur, reads may fail but are never wrong."""
    nodes = layout(1, count=6)
    reads = AprilTagIdentifier().identify(frame(nodes, noise=8.0, blur=0.8, seed=1), _circles(nodes))
    assert all(r is None or r.tag == n.tag for r, n in zip(reads, nodes))
    assert sum(r is not None for r in reads) >= 3


def test_discs_without_tags_give_no_read():
    """Discs carrying no tag give None for every circle."""
    nodes = [SceneNode(n.u, n.v, n.r) for n in layout(2)]
    assert AprilTagIdentifier().identify(frame(nodes), _circles(nodes)) == [None] * len(nodes)


def test_no_circles_no_reads():
    """An empty circle list gives an empty read list."""
    assert AprilTagIdentifier().identify(frame([]), []) == []


def test_tag_table_maps_tag_to_node():
    """A tag table turns the tag id into the node id, and an unlisted tag names no node."""
    nodes = layout(3, count=2)
    table = {nodes[0].tag: 900}
    reads = AprilTagIdentifier(AprilTagConfig(tag_table=table)).identify(frame(nodes), _circles(nodes))
    assert reads[0].tag == nodes[0].tag and reads[0].node == 900
    assert reads[1].tag == nodes[1].tag and reads[1].node is None


def test_clean_read_has_zero_hamming_and_large_margin():
    """A clean read measures hamming 0 and a margin of tens of grey levels."""
    nodes = [SceneNode(320, 240, 60, tag=42, tag_size=0.8)]
    (read,) = AprilTagIdentifier().identify(frame(nodes), _circles(nodes))
    assert read.hamming == 0 and read.margin > 40


def test_flipped_cells_raise_the_measured_hamming():
    """tag_quality counts flipped data cells as hamming distance."""
    d = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
    code = cv2.aruco.generateImageMarker(d, 5, 8, borderBits=1) > 127
    img = np.where(code, 220, 30).astype(np.uint8)
    big = cv2.resize(img, (160, 160), interpolation=cv2.INTER_NEAREST)
    corners = np.array([[0, 0], [160, 0], [160, 160], [0, 160]], float) - 0.5
    assert tag_quality(big, corners, code)[0] == 0
    flipped = code.copy()
    flipped[2, 3] ^= True
    flipped[4, 5] ^= True
    assert tag_quality(big, corners, flipped)[0] == 2


def test_strict_filters_reject_weak_reads():
    """An impossible margin threshold rejects every read."""
    nodes = layout(0)
    reads = AprilTagIdentifier(AprilTagConfig(min_margin=1000)).identify(frame(nodes), _circles(nodes))
    assert reads == [None] * len(nodes)


def _sticker_frame(tags_radii):
    """Grey floor; per node a light disc holding a tag on a whiter paper square (the sticker's edge)."""
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
    img = np.full((480, 800), 100, np.uint8)
    nodes = []
    for k, (tag, r) in enumerate(tags_radii):
        cx, cy = 120 + 220 * k, 240
        cv2.circle(img, (cx, cy), r, 225, -1, cv2.LINE_AA)
        side = r
        code = cv2.aruco.generateImageMarker(dictionary, tag, side, borderBits=1)
        pad = side // 8
        paper = cv2.resize(cv2.copyMakeBorder(code, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=255),
                           (side, side), interpolation=cv2.INTER_AREA)
        img[cy - side // 2:cy - side // 2 + side, cx - side // 2:cx - side // 2 + side] = paper
        nodes.append(Circle(float(cx), float(cy), float(r), 1.0))
    return img, nodes


def test_tags_on_paper_stickers_of_large_nodes_are_read():
    """A tag nested in its sticker's paper square is read on large nodes too (30-90 px radius)."""
    tags_radii = [(5, 90), (7, 70), (12, 45), (21, 30)]
    img, circles = _sticker_frame(tags_radii)
    reads = AprilTagIdentifier().identify(img, circles)
    assert [r.node if r else None for r in reads] == [t for t, _ in tags_radii]
