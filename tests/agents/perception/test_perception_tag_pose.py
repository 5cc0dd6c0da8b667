"""The AprilTag-pose baseline: exact on exact corners, root-only, yaw resolved towards the previous step."""

import numpy as np

from agents.perception.sphere_tags import StickerLayout
from agents.perception.tag_pose import TagPoseConfig, estimate_log_tag_pose, print_geometry
from decentral.observations import Camera, ObservationLog, Pose, Step

K = np.array([[760.0, 0, 512], [0, 760.0, 384], [0, 0, 1]])
R0 = 0.06
CAM = Pose(np.array([[0.0, 0, 1], [-1, 0, 0], [0, -1, 0]]), np.array([0.1, 0.0, 0.2]))  # looks along +x of H0
LAYOUT = StickerLayout.around()


def _rz(a):
    return np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])


def _corners(p_root, yaw, sticker):
    """Image corners of ``sticker`` on a target root node at ``p_root`` (H0) with yaw ``yaw``."""
    t = np.tan(LAYOUT.half_angle)
    ax, up, right = LAYOUT.axes[sticker], LAYOUT.up[sticker], LAYOUT.right[sticker]
    pts = []
    for s1, s2 in ((-t, t), (t, t), (t, -t), (-t, -t)):
        n = ax + s1 * right + s2 * up
        n = n / np.linalg.norm(n)
        x_h0 = p_root + R0 * (_rz(yaw) @ n)
        x_c = CAM.R.T @ (x_h0 - CAM.p)
        q = K @ x_c
        pts.append(q[:2] / q[2])
    return np.array(pts)


def _log(steps, p_root):
    cam = Camera("A0", "cam0", K, Pose(np.eye(3), np.zeros(3)), CAM)
    config = {"A0": {0: np.zeros(3)}, "A1": {5: np.zeros(3), 6: np.array([0.2, 0.0, 0.0])}}
    return ObservationLog(R0, ("A0", "A1"), {"A0/cam0": cam}, tuple(Step(0.2 * k, config) for k in range(steps)))


def test_print_geometry_of_the_default_layout():
    """The print's corner square has side 2 r0 tan(h) / sqrt(1 + 2 tan^2 h) at depth r0 / sqrt(...)."""
    side, depth = print_geometry(LAYOUT, R0)
    t = np.tan(LAYOUT.half_angle)
    assert np.isclose(side, 2 * R0 * t / np.sqrt(1 + 2 * t * t)) and np.isclose(depth, R0 / np.sqrt(1 + 2 * t * t))


def test_exact_corners_give_the_root_position_and_yaw():
    """Exact corners of a near root node's sticker recover its position (1 mm) and its yaw up to the
    sticker spacing (45 deg: copies of the tag sit all around the equator)."""
    p_root, yaw = np.array([0.55, 0.05, 0.1]), np.pi + 0.1  # sticker 0 (+x of the node) faces the camera
    est = estimate_log_tag_pose(_log(1, p_root), {"A0/cam0": [{5: _corners(p_root, yaw, 0)}]})
    pose = est.steps[0].poses["A1"]
    assert np.allclose(pose.p, p_root, atol=1e-3)
    spacing = np.pi / 4
    assert abs((pose.theta - yaw + spacing / 2) % spacing - spacing / 2) < np.radians(0.5)


def test_far_small_tag_keeps_the_centre_but_not_the_normal():
    """At 1.8 m (a 15 px print) the tag's centre is still right within 3 cm: its normal is the weak part."""
    p_root, yaw = np.array([1.8, 0.3, -0.1]), np.pi + 0.1
    est = estimate_log_tag_pose(_log(1, p_root), {"A0/cam0": [{5: _corners(p_root, yaw, 0)}]})
    assert np.linalg.norm(est.steps[0].poses["A1"].p - p_root) < 0.03


def test_non_root_tags_are_not_used():
    """A tag read only on a non-root node places nothing (the paper's baseline uses the root tag)."""
    p_root = np.array([1.8, 0.3, -0.1])
    est = estimate_log_tag_pose(_log(1, p_root), {"A0/cam0": [{6: _corners(p_root, np.pi, 0)}]})
    assert est.steps[0].poses == {}


def test_sticker_ambiguity_resolves_towards_the_previous_yaw():
    """Seen through another sticker, the yaw is taken as the copy nearest the previous step's."""
    p_root, yaw = np.array([0.55, 0.0, 0.1]), np.pi + 0.05
    reads = [{5: _corners(p_root, yaw, 0)}, {5: _corners(p_root, yaw - np.pi / 4, 1)}]
    est = estimate_log_tag_pose(_log(2, p_root), {"A0/cam0": reads}, TagPoseConfig(layout=LAYOUT))
    assert abs((est.steps[1].poses["A1"].theta - est.steps[0].poses["A1"].theta + np.pi) % (2 * np.pi) - np.pi) < np.radians(0.5)


def test_degenerate_corners_fail_softly():
    """Collapsed corners place nothing and raise no error."""
    est = estimate_log_tag_pose(_log(1, np.zeros(3)), {"A0/cam0": [{5: np.zeros((4, 2))}]})
    assert isinstance(est.steps[0].poses, dict)
