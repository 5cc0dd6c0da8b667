"""Properties of the pinhole model in sims.simulation.world.camera (Liu et al. 2024 eq. (1))."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from decentral.observations import Pose
from sims.simulation.world.camera import CameraSpec, covered_fraction, default_K, project_nodes, visible_mask
from decentral.geometry import rotz
from sims.simulation.world.mounts import CAM_LOOKS_ALONG_X, camera_mount

K = default_K()
R0 = 0.06


def _random_rotation(rng):
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_eq1_back_projection_recovers_the_centre(seed):
    """K^-1 (f r0 / r) [u, v, 1] of a noiseless detection is the node centre in the camera frame."""
    rng = np.random.default_rng(seed)
    cam = Pose(_random_rotation(rng), rng.normal(size=3))
    pc = np.column_stack([rng.uniform(-1, 1, 5), rng.uniform(-1, 1, 5), rng.uniform(0.3, 6, 5)])
    centres = cam.apply(pc)
    uvr, depth = project_nodes(K, cam, centres, R0)
    back = (np.linalg.inv(K) @ np.column_stack([uvr[:, :2], np.ones(5)]).T).T * (K[0, 0] * R0 / uvr[:, 2])[:, None]
    assert np.allclose(back, pc, atol=1e-9)
    assert np.allclose(depth, pc[:, 2])


def test_contract_mount_looks_along_strut_x():
    """With the contract's cam_in_strut, a point ahead on the strut's +x projects to the principal point."""
    cam = Pose(np.eye(3), np.zeros(3)).compose(Pose(CAM_LOOKS_ALONG_X, np.zeros(3)))
    uvr, depth = project_nodes(K, cam, np.array([[2.0, 0, 0], [2.0, -0.5, 0], [2.0, 0, -0.5]]), R0)
    assert depth[0] == pytest.approx(2.0)
    assert uvr[0, :2] == pytest.approx([512, 384])
    assert uvr[1, 0] > 512  # strut -y is image right
    assert uvr[2, 1] > 384  # strut -z is image down


def test_pitched_mount_sees_the_floor_below_the_axis():
    """A camera tilted down puts a point straight ahead at its own height above the image centre."""
    cam = Pose(rotz(0.0), np.zeros(3)).compose(camera_mount(np.radians(20), offset=(0, 0, 0)))
    uvr, _ = project_nodes(K, cam, np.array([[2.0, 0, 0]]), R0)
    assert uvr[0, 1] < 384


def test_visibility_needs_the_whole_circle_in_view_and_in_front():
    """Nodes behind the camera, beyond range, or cut by the image border are not visible."""
    spec = CameraSpec(K, max_range=5.0)
    cam = Pose(np.eye(3), np.zeros(3))
    pts = np.array([[0, 0, 2.0], [0, 0, -2.0], [0, 0, 8.0], [1.35, 0, 2.0]])
    uvr, depth = project_nodes(K, cam, pts, R0)
    assert visible_mask(spec, uvr, depth).tolist() == [True, False, False, False]


def test_nearer_sphere_covers_farther_one():
    """A sphere right in front of another covers it fully; the farther one covers nothing of it."""
    cam = Pose(np.eye(3), np.zeros(3))
    uvr, depth = project_nodes(K, cam, np.array([[0, 0, 1.5], [0, 0, 2.0], [0.8, 0, 2.0]]), R0)
    frac = covered_fraction(uvr, depth)
    assert frac[1] == pytest.approx(1.0)
    assert frac[0] == 0.0 and frac[2] == 0.0


def test_partial_cover_is_between_zero_and_one():
    """Two overlapping circles give the farther one a covered fraction strictly inside (0, 1)."""
    cam = Pose(np.eye(3), np.zeros(3))
    uvr, depth = project_nodes(K, cam, np.array([[0, 0, 1.5], [0.07, 0, 2.0]]), R0)
    assert 0.0 < covered_fraction(uvr, depth)[1] < 1.0


@settings(max_examples=40, deadline=None)
@given(st.floats(-0.55, 0.55), st.floats(-0.45, 0.45), st.floats(0.4, 5.0))
def test_silhouette_to_eq1_circle_inverts_the_silhouette(tx, ty, z):
    """Mapping a sphere's exact silhouette circle back gives its eq. (1) circle."""
    from sims.simulation.world.camera import eq1_circle_from_silhouette, silhouette_circle

    c = np.array([tx * z, ty * z, z])
    su, sv, sr = silhouette_circle(K, c, R0)
    u, v, r = eq1_circle_from_silhouette(K, su, sv, sr, R0)
    uvr, _ = project_nodes(K, Pose(np.eye(3), np.zeros(3)), c[None], R0)
    assert np.allclose([u, v, r], uvr[0], atol=1e-6)


def test_silhouette_is_larger_than_eq1_off_axis():
    """Off the axis the exact silhouette is bigger than f r0 / z_c (eq. (1)'s model), on the axis not by much."""
    from sims.simulation.world.camera import silhouette_circle

    on = silhouette_circle(K, np.array([0.0, 0.0, 1.5]), R0)[2] / (K[0, 0] * R0 / 1.5)
    off = silhouette_circle(K, np.array([1.5 * np.tan(np.radians(30)), 0.0, 1.5]), R0)[2] / (K[0, 0] * R0 / 1.5)
    assert 1.0 < on < 1.002 and 1.07 < off < 1.08
