"""Properties of the planar geometry helpers (Liu et al. 2024 eq. (1), (16), (17))."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from decentral.geometry import backproject, project_so2, rot2, rotz, wrap_angle, yaw_of

angles = st.floats(-10, 10, allow_nan=False)
finite = st.floats(-5, 5, allow_nan=False)


@given(angles)
def test_yaw_of_inverts_rotz(theta):
    """yaw_of(rotz(theta)) is theta wrapped into [-pi, pi)."""
    assert abs(wrap_angle(yaw_of(rotz(theta)) - theta)) < 1e-9


@given(st.lists(finite, min_size=4, max_size=4))
def test_project_so2_returns_a_rotation(entries):
    """eq. (17) always returns an SO(2) matrix."""
    R = project_so2(np.array(entries).reshape(1, 2, 2))[0]
    assert np.allclose(R.T @ R, np.eye(2), atol=1e-9)
    assert np.isclose(np.linalg.det(R), 1.0)


@given(angles, st.floats(0.1, 10))
def test_project_so2_recovers_scaled_rotations(theta, scale):
    """A positively scaled rotation projects back to that rotation."""
    assert np.allclose(project_so2(scale * rot2(theta)[None])[0], rot2(theta), atol=1e-9)


@given(angles, angles)
def test_project_so2_is_nearest_among_rotations(theta, other):
    """No other rotation is closer in the Frobenius norm to the input than its projection."""
    Y = rot2(theta) + 0.3 * np.array([[1.0, 0.2], [-0.4, 0.1]])
    R = project_so2(Y[None])[0]
    assert np.linalg.norm(Y - R) <= np.linalg.norm(Y - rot2(other)) + 1e-9


@settings(max_examples=50)
@given(st.floats(-1.5, 1.5), st.floats(-1.0, 1.0), st.floats(0.3, 8.0), st.floats(0.02, 0.2))
def test_backproject_inverts_pinhole_projection(x, y, z, radius):
    """eq. (1) recovers a centre from its projection and r = f r0 / z."""
    K = np.array([[760.0, 0, 512], [0, 760.0, 384], [0, 0, 1]])
    point = np.array([x, y, z])
    uvw = K @ point
    u, v, r = uvw[0] / uvw[2], uvw[1] / uvw[2], 760.0 * radius / z
    assert np.allclose(backproject(K, [u], [v], [r], radius)[0], point, atol=1e-9)
