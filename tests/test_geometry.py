"""SE(3), intrinsics and Blender<->OpenCV conventions: oracles and properties."""

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from blendgen import geometry as g

angles = st.floats(-math.pi, math.pi, allow_nan=False)
coords = st.floats(-1e3, 1e3, allow_nan=False)


def random_T(rng):
    q = rng.standard_normal(4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    R = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    return g.make_T(R, rng.uniform(-10, 10, 3))


def test_K_from_fov_golden():
    # 640 px over 60 deg: fx = 320 / tan(30 deg) = 554.2563; pixel centres at integers.
    K = g.intrinsics_from_hfov(640, 480, math.radians(60))
    assert K[0, 0] == pytest.approx(554.25625842, abs=1e-6)
    assert K[1, 1] == K[0, 0]
    assert (K[0, 2], K[1, 2]) == (319.5, 239.5)


def test_K_equals_blender_lens_formula():
    # fx = lens_mm * W / sensor_width_mm with lens = sensor/2 / tan(fov/2)
    W, sensor, fov = 1280, 36.0, math.radians(75)
    lens = sensor / 2 / math.tan(fov / 2)
    K = g.intrinsics_from_hfov(W, 720, fov)
    assert K[0, 0] == pytest.approx(lens * W / sensor, rel=1e-12)


@pytest.mark.parametrize("fov", [0.0, math.pi, -0.1, 4.0])
def test_K_rejects_impossible_fov(fov):
    with pytest.raises(ValueError, match="hfov"):
        g.intrinsics_from_hfov(640, 480, fov)


@given(st.floats(0.02, math.pi - 0.02), st.integers(16, 8192), st.integers(16, 8192))
def test_fov_round_trip(fov, w, h):
    K = g.intrinsics_from_hfov(w, h, fov)
    assert g.hfov_from_K(K, w) == pytest.approx(fov, rel=1e-12)


@given(st.integers(0, 2**32 - 1))
def test_invert_and_compose(seed):
    rng = np.random.default_rng(seed)
    A, B = random_T(rng), random_T(rng)
    assert np.allclose(g.invert_T(A) @ A, np.eye(4), atol=1e-9)
    assert np.allclose(g.invert_T(A @ B), g.invert_T(B) @ g.invert_T(A), atol=1e-9)


def test_long_chain_stays_orthonormal():
    T = np.eye(4)
    step = g.make_T(g.rpy_to_R(1e-3, -2e-3, 3e-3), [0.01, 0, 0])
    for _ in range(100_000):
        T = T @ step
    R = T[:3, :3]
    # drift of plain float64 products over 1e5 steps stays far below 1e-9 per axis
    assert abs(np.linalg.det(R) - 1) < 1e-9
    assert np.allclose(R.T @ R, np.eye(3), atol=1e-9)
    assert np.allclose(g.orthonormalize(R) @ g.orthonormalize(R).T, np.eye(3), atol=1e-12)


@given(angles, st.floats(-1.5, 1.5), angles)
def test_rpy_round_trip(r, p, y):
    R = g.rpy_to_R(r, p, y)
    assert np.allclose(g.rpy_to_R(*g.R_to_rpy(R)), R, atol=1e-9)


def test_blender_opencv_camera_axes():
    # A Blender camera at identity looks down -Z with +Y up: OpenCV z (forward) = -Z_world,
    # OpenCV y (down) = -Y_world.
    T = g.T_world_cam_from_blender_matrix_world(np.eye(4))
    assert np.allclose(T[:3, 2], [0, 0, -1]) and np.allclose(T[:3, 1], [0, -1, 0])
    M = g.blender_matrix_world_from_T_world_cam(T)
    assert np.allclose(M, np.eye(4))


@given(st.integers(0, 2**32 - 1))
def test_project_unproject_round_trip(seed):
    rng = np.random.default_rng(seed)
    K = g.intrinsics_from_hfov(640, 480, rng.uniform(0.3, 2.5))
    P = np.column_stack([rng.uniform(-5, 5, 50), rng.uniform(-5, 5, 50), rng.uniform(0.01, 1e4, 50)])
    uv = g.project(K, P)
    assert np.allclose(g.unproject(K, uv, P[:, 2]), P, rtol=1e-9, atol=1e-9)


def test_points_behind_camera_project_to_nan():
    K = g.intrinsics_from_hfov(640, 480, 1.0)
    uv = g.project(K, [[0, 0, -1], [0, 0, 0], [0, 0, 1]])
    assert np.isnan(uv[:2]).all() and np.allclose(uv[2], [K[0, 2], K[1, 2]])


def test_range_from_planar_depth():
    K = g.intrinsics_from_hfov(640, 480, math.radians(90))  # fx = 320 - ... corner ray ~ 45 deg
    z = np.full((480, 640), 2.0, np.float32)
    r = g.planar_depth_to_range(z, K)
    assert r[240, 320] == pytest.approx(2.0 * math.sqrt(1 + (0.5 / K[0, 0]) ** 2 + (0.5 / K[1, 1]) ** 2), rel=1e-6)
    u, v = 0 - K[0, 2], 0 - K[1, 2]
    assert r[0, 0] == pytest.approx(2.0 * math.sqrt(1 + (u / K[0, 0]) ** 2 + (v / K[1, 1]) ** 2), rel=1e-6)


def test_rotation_angle_near_0_and_pi():
    assert g.rotation_angle(np.eye(3)) == 0.0
    assert g.rotation_angle(g.rot_z(math.pi)) == pytest.approx(math.pi, abs=1e-12)
    assert g.rotation_angle(g.rot_x(1e-9)) == pytest.approx(1e-9, rel=1e-6)
